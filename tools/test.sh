#!/usr/bin/env bash
# Sets up everything the project needs, builds it and runs every test.
#
#   tools/test.sh [extra CMake configure args...]      e.g. tools/test.sh -DVL_MAX_LANDMARKS=64
#
# Steps: Debian packages (only what is missing), Unity, Python venv (only when requirements.txt
# changed), CMake configure (Release, -Werror), build, CTest, pytest. Ends with one line
# `N passed, N failed, N skipped` over all CTest and pytest tests, and exits non-zero on any failure.
#
# Environment (all optional):
#   BUILD_DIR         build directory (default build, relative to the repo root)
#   BUILD_TYPE        CMake build type (default Release)
#   JOBS              build parallelism (default 2)
#   VL_MAX_LANDMARKS  passed as -DVL_MAX_LANDMARKS=...
#   UNITY_ROOT        use this Unity tree (-DUNITY_ROOT=...) and fetch nothing
#   CTEST_TIMEOUT     default per-test timeout in seconds (default 600)
#   CTEST_PARALLEL_LEVEL, VENV_DIR, VL_PYTHON, REQUIREMENTS, VL_SKIP_APT: see tools/setup.sh
set -Eeuo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$REPO_ROOT"
export VL_REPO_ROOT="$REPO_ROOT"
export DEBIAN_FRONTEND=noninteractive
# shellcheck source=tools/setup.sh
source "$REPO_ROOT/tools/setup.sh"

case "${1:-}" in
  -h|--help) sed -n '2,19p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 0 ;;
esac

BUILD_DIR="${BUILD_DIR:-build}"
case "$BUILD_DIR" in /*) ;; *) BUILD_DIR="$REPO_ROOT/$BUILD_DIR" ;; esac
BUILD_TYPE="${BUILD_TYPE:-Release}"
JOBS="${JOBS:-2}"
VENV_DIR="${VENV_DIR:-$REPO_ROOT/.venv}"
export VENV_DIR
RESULTS_DIR="$BUILD_DIR/test-results"

# ---- step bookkeeping: headers, timing, and saying which step failed --------------------------
STEPS_TOTAL=7
STEP_NO=0
STEP_NAME="start-up"
STEP_START=$SECONDS
ERR_REPORTED=0

step() {
  if [ "$STEP_NO" -gt 0 ]; then
    printf -- '---- done: %s (%ds)\n' "$STEP_NAME" "$((SECONDS - STEP_START))"
  fi
  STEP_NO=$((STEP_NO + 1))
  STEP_NAME="$1"
  STEP_START=$SECONDS
  printf '\n==== [%d/%d] %s ====\n' "$STEP_NO" "$STEPS_TOTAL" "$STEP_NAME"
}

# shellcheck disable=SC2317  # both run from traps
on_err() {
  if [ "$ERR_REPORTED" -eq 0 ]; then
    ERR_REPORTED=1
    case "$3" in
      return*|exit*) printf 'ERROR: exit status %s at %s line %s\n' "$1" "${BASH_SOURCE[1]:-?}" "$2" >&2 ;;
      *) printf 'ERROR: command failed (exit %s, %s line %s): %s\n' "$1" "${BASH_SOURCE[1]:-?}" "$2" "$3" >&2 ;;
    esac
  fi
}
# shellcheck disable=SC2317
on_exit() {
  local rc=$?
  if [ "$rc" -ne 0 ]; then
    printf '\n==== tools/test.sh FAILED in step [%d/%d] %s (exit %d) ====\n' \
      "$STEP_NO" "$STEPS_TOTAL" "$STEP_NAME" "$rc" >&2
  fi
}
trap 'on_err $? $LINENO "$BASH_COMMAND"' ERR
trap on_exit EXIT

# ---- set-up ------------------------------------------------------------------------------------
step "Debian packages"
vl_install_debs

step "Unity test framework"
vl_setup_unity

step "Python venv"
vl_setup_venv

# ---- build -------------------------------------------------------------------------------------
step "CMake configure ($BUILD_TYPE, $BUILD_DIR)"
cmake_args=(
  -S "$REPO_ROOT" -B "$BUILD_DIR"
  -DCMAKE_BUILD_TYPE="$BUILD_TYPE"
  -DVL_WERROR=ON
  -DUNITY_ROOT="$VL_UNITY_ROOT"
)
if [ -n "${VL_MAX_LANDMARKS:-}" ]; then cmake_args+=(-DVL_MAX_LANDMARKS="$VL_MAX_LANDMARKS"); fi
cmake_args+=("$@")   # the caller's own configure args come last, so they win
echo "$(cmake --version | head -n1); $(g++ --version | head -n1); $("$VENV_DIR/bin/python" --version)"
cmake "${cmake_args[@]}"

step "Build (-j$JOBS)"
cmake --build "$BUILD_DIR" -j "$JOBS"

# ---- tests: run both suites even when the first fails, then count ------------------------------
export VL_BUILD_DIR="$BUILD_DIR"   # lets the Python tests find generated LCM types and binaries
rm -rf "$RESULTS_DIR"
mkdir -p "$RESULTS_DIR"

step "CTest"
ctest_rc=0
(cd "$BUILD_DIR" && ctest --output-on-failure --timeout "${CTEST_TIMEOUT:-600}") 2>&1 \
  | tee "$RESULTS_DIR/ctest.log" || ctest_rc=$?

# ctest's own summary: "NN% tests passed, F tests failed out of T"; skipped and disabled tests
# count as neither passed nor failed there, and are listed under "The following tests did not run:".
ct_total=0 ct_failed=0 ct_skipped=0
summary_line="$(grep -E '[0-9]+ tests? failed out of [0-9]+' "$RESULTS_DIR/ctest.log" | tail -n1 || true)"
if [ -n "$summary_line" ]; then
  ct_failed="$(sed -E 's/.* ([0-9]+) tests? failed out of ([0-9]+).*/\1/' <<<"$summary_line")"
  ct_total="$(sed -E 's/.* ([0-9]+) tests? failed out of ([0-9]+).*/\2/' <<<"$summary_line")"
  ct_skipped="$(awk '/^The following tests did not run:/ { on = 1; next }
                     on && /^[[:space:]]*$/ { on = 0 }
                     on && /\((Skipped|Disabled)\)[[:space:]]*$/ { n++ }
                     END { print n + 0 }' "$RESULTS_DIR/ctest.log")"
elif [ "$ctest_rc" -ne 0 ]; then
  ct_failed=1   # ctest died before summarising: count it as one failure
fi
ct_passed=$((ct_total - ct_failed - ct_skipped))
[ "$ct_passed" -ge 0 ] || ct_passed=0
if [ "$ctest_rc" -ne 0 ]; then
  echo "CTest exited with status $ctest_rc"
  [ "$ct_failed" -gt 0 ] || ct_failed=1
fi

step "pytest (tests/python)"
py_rc=0 py_passed=0 py_failed=0 py_skipped=0
if [ -d "$REPO_ROOT/tests/python" ]; then
  "$VENV_DIR/bin/python" -m pytest "$REPO_ROOT/tests/python" -ra -p no:cacheprovider \
    --junitxml="$RESULTS_DIR/pytest.xml" </dev/null || py_rc=$?
  if [ "$py_rc" -eq 5 ]; then
    echo "pytest collected no tests"
    py_rc=0
  fi
  if [ -f "$RESULTS_DIR/pytest.xml" ]; then
    py_counts="$("$VENV_DIR/bin/python" - "$RESULTS_DIR/pytest.xml" <<'EOF'
import sys
import xml.etree.ElementTree as ET

root = ET.parse(sys.argv[1]).getroot()
suites = [root] if root.tag == "testsuite" else root.iter("testsuite")
tests = failed = skipped = 0
for s in suites:
    tests += int(s.get("tests", 0))
    failed += int(s.get("failures", 0)) + int(s.get("errors", 0))
    skipped += int(s.get("skipped", 0))
print(max(tests - failed - skipped, 0), failed, skipped)
EOF
    )" || py_counts="0 1 0"   # unreadable report: count it as one failure
    read -r py_passed py_failed py_skipped <<<"$py_counts"
  fi
  if [ "$py_rc" -ne 0 ]; then
    echo "pytest exited with status $py_rc"
    [ "$py_failed" -gt 0 ] || py_failed=1
  fi
else
  echo "no tests/python directory: nothing to run"
fi
printf -- '---- done: %s (%ds)\n' "$STEP_NAME" "$((SECONDS - STEP_START))"

# ---- summary -----------------------------------------------------------------------------------
trap - ERR
passed=$((ct_passed + py_passed))
failed=$((ct_failed + py_failed))
skipped=$((ct_skipped + py_skipped))
status=0
if [ "$ctest_rc" -ne 0 ] || [ "$py_rc" -ne 0 ] || [ "$failed" -ne 0 ]; then
  status=1
fi
trap - EXIT
echo
echo "==== Summary: CTest $ct_passed/$ct_failed/$ct_skipped, pytest $py_passed/$py_failed/$py_skipped" \
     "(passed/failed/skipped): $([ "$status" -eq 0 ] && echo OK || echo FAILED) ===="
# The closing line CI reads: keep it last and alone on its line.
echo "$passed passed, $failed failed, $skipped skipped"
exit "$status"
