#!/usr/bin/env bash
# Sets up everything the project needs, builds it and runs every test.
#
#   tools/test.sh [extra CMake configure args...]      e.g. tools/test.sh -DVL_MAX_LANDMARKS=64
#
# Steps: Debian packages (only what is missing), Unity, Python venv (only when requirements.txt
# changed), CMake configure (Release, -Werror), build, CTest, pytest, then the same CTest suite
# built with AddressSanitizer and UndefinedBehaviorSanitizer (the allocation counters excluded:
# ASan owns malloc; the plain CTest above runs them), then each libFuzzer harness for a bounded
# time (tools/fuzz.sh; when clang is there). Ends with one line `N passed, N failed, N skipped`
# over all of it (each fuzzer counts as one test), and exits non-zero on any failure.
#
# Environment (all optional):
#   BUILD_DIR         build directory (default build, relative to the repo root)
#   BUILD_TYPE        CMake build type (default Release)
#   JOBS              build parallelism (default 2)
#   VL_MAX_LANDMARKS  passed as -DVL_MAX_LANDMARKS=...
#   UNITY_ROOT        use this Unity tree (-DUNITY_ROOT=...) and fetch nothing
#   CTEST_TIMEOUT     default per-test timeout in seconds (default 600)
#   CTEST_PARALLEL_LEVEL tests CTest runs at once (default JOBS; each test has its own network
#                     namespace and directories, so they do not meet)
#   VENV_DIR, VL_PYTHON, REQUIREMENTS, VL_SKIP_APT: see tools/setup.sh
#   VL_SANITIZE_STAGE 0 skips the sanitizer build and its CTest (default 1)
#   SANITIZE_BUILD_DIR its build directory (default build-asan); VL_SANITIZE its sanitizers
#                     (default address,undefined); SANITIZE_BUILD_TYPE its CMake build type
#                     (default RelWithDebInfo: -O2, where -O3 took the instrumented Eigen shim
#                     160 s of a 2-core machine to compile, and its tests were no faster)
#   VL_FUZZ_SECONDS   run time of each fuzzer in seconds (default 60; 0 skips the fuzz step)
#   FUZZ_BUILD_DIR    the fuzzers' build directory (default build-fuzz); see tools/fuzz.sh
set -Eeuo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$REPO_ROOT"
export VL_REPO_ROOT="$REPO_ROOT"
export DEBIAN_FRONTEND=noninteractive
# shellcheck source=tools/setup.sh
source "$REPO_ROOT/tools/setup.sh"

case "${1:-}" in
  -h|--help) awk 'NR > 1 && !/^#/ { exit } NR > 1 { sub(/^# ?/, ""); print }' "${BASH_SOURCE[0]}"; exit 0 ;;
esac

BUILD_DIR="${BUILD_DIR:-build}"
case "$BUILD_DIR" in /*) ;; *) BUILD_DIR="$REPO_ROOT/$BUILD_DIR" ;; esac
BUILD_TYPE="${BUILD_TYPE:-Release}"
JOBS="${JOBS:-2}"
CTEST_JOBS="${CTEST_PARALLEL_LEVEL:-$JOBS}"
VENV_DIR="${VENV_DIR:-$REPO_ROOT/.venv}"
export VENV_DIR
RESULTS_DIR="$BUILD_DIR/test-results"
SANITIZE_STAGE="${VL_SANITIZE_STAGE:-1}"
SANITIZERS="${VL_SANITIZE:-address,undefined}"
SANITIZE_BUILD_DIR="${SANITIZE_BUILD_DIR:-build-asan}"
SANITIZE_BUILD_TYPE="${SANITIZE_BUILD_TYPE:-RelWithDebInfo}"
case "$SANITIZE_BUILD_DIR" in /*) ;; *) SANITIZE_BUILD_DIR="$REPO_ROOT/$SANITIZE_BUILD_DIR" ;; esac
FUZZ_SECONDS="${VL_FUZZ_SECONDS:-60}"

# ---- step bookkeeping: headers, timing, and saying which step failed --------------------------
STEPS_TOTAL=9
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

# ---- tests: run every suite even when one fails, then count ---------------------------------------
# ctest_counts JUNIT RC: prints "passed failed skipped" from CTest's JUnit report (--output-junit)
# and its exit status: a test that ran and passed, failed, or did not run (skipped, disabled).
ctest_counts() {
  local junit=$1 rc=$2 counts p f s
  counts="$("$VENV_DIR/bin/python" - "$junit" 2>/dev/null <<'EOF' || true
import sys
import xml.etree.ElementTree as ET
status = [c.get("status") for c in ET.parse(sys.argv[1]).getroot().iter("testcase")]
print(status.count("run"), status.count("fail"), len(status) - status.count("run") - status.count("fail"))
EOF
)"
  if [ -z "$counts" ]; then
    counts="0 1 0" # no report: ctest died before writing it, one failure
  elif [ "$rc" -ne 0 ]; then
    echo "CTest exited with status $rc" >&2
    read -r p f s <<<"$counts"
    [ "$f" -gt 0 ] || f=1
    counts="$p $f $s"
  fi
  echo "$counts"
}

export VL_BUILD_DIR="$BUILD_DIR"   # lets the Python tests find generated LCM types and binaries
rm -rf "$RESULTS_DIR"
mkdir -p "$RESULTS_DIR"

step "CTest"
ctest_rc=0
(cd "$BUILD_DIR" && ctest -j "$CTEST_JOBS" --output-on-failure --timeout "${CTEST_TIMEOUT:-600}" \
  --output-junit "$RESULTS_DIR/ctest.xml") 2>&1 | tee "$RESULTS_DIR/ctest.log" || ctest_rc=$?

read -r ct_passed ct_failed ct_skipped <<<"$(ctest_counts "$RESULTS_DIR/ctest.xml" "$ctest_rc")"

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

# ---- sanitizers: the CTest suite again, built with ASan + UBSan in its own directory -------------
step "Sanitizer build and CTest ($SANITIZERS, $SANITIZE_BUILD_TYPE, $SANITIZE_BUILD_DIR)"
san_rc=0 san_passed=0 san_failed=0 san_skipped=0
if [ "$SANITIZE_STAGE" = 0 ]; then
  echo "skipped (VL_SANITIZE_STAGE=0)"
  san_skipped=1
else
  san_args=("${cmake_args[@]}")
  san_args[3]="$SANITIZE_BUILD_DIR"   # -S ROOT -B DIR ...: the same configuration, another directory
  san_args+=(-DVL_SANITIZE="$SANITIZERS" -DCMAKE_BUILD_TYPE="$SANITIZE_BUILD_TYPE")
  san_log="$RESULTS_DIR/ctest-sanitize.log"
  if cmake "${san_args[@]}" >"$RESULTS_DIR/sanitize-configure.log" 2>&1 \
     && cmake --build "$SANITIZE_BUILD_DIR" -j "$JOBS" >"$RESULTS_DIR/sanitize-build.log" 2>&1; then
    echo "built in $SANITIZE_BUILD_DIR (output: $RESULTS_DIR/sanitize-build.log)"
    # Findings abort the test (-fno-sanitize-recover, halt_on_error) with a stack trace.
    (cd "$SANITIZE_BUILD_DIR" && \
      ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1}" \
      UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}" \
      ctest -j "$CTEST_JOBS" --output-on-failure --timeout "${CTEST_TIMEOUT:-600}" \
        --output-junit "$RESULTS_DIR/ctest-sanitize.xml") \
      2>&1 | tee "$san_log" || san_rc=$?
    read -r san_passed san_failed san_skipped <<<"$(ctest_counts "$RESULTS_DIR/ctest-sanitize.xml" "$san_rc")"
  else
    san_rc=1 san_failed=1
    echo "sanitizer configure or build FAILED; the end of its output:"
    tail -n 40 "$RESULTS_DIR/sanitize-build.log" 2>/dev/null || tail -n 40 "$RESULTS_DIR/sanitize-configure.log"
  fi
fi

# ---- fuzzers: each libFuzzer harness for a bounded time (tools/fuzz.sh) -------------------------
step "Fuzzers (${FUZZ_SECONDS}s each)"
fz_rc=0 fz_passed=0 fz_failed=0 fz_skipped=0
fz_harnesses=(messages log_reader)
if [ "$FUZZ_SECONDS" = 0 ]; then
  echo "skipped (VL_FUZZ_SECONDS=0)"
  fz_skipped=${#fz_harnesses[@]}
elif ! command -v clang >/dev/null 2>&1; then
  echo "skipped: clang not found (tools/setup.sh installs it)"
  fz_skipped=${#fz_harnesses[@]}
elif ! UNITY_ROOT="$VL_UNITY_ROOT" JOBS="$JOBS" bash "$REPO_ROOT/tools/fuzz.sh" --build-only \
       >"$RESULTS_DIR/fuzz-build.log" 2>&1; then
  fz_rc=1 fz_failed=1
  echo "fuzzer build FAILED; the end of its output:"
  tail -n 40 "$RESULTS_DIR/fuzz-build.log"
else
  echo "built (output: $RESULTS_DIR/fuzz-build.log)"
  # The harnesses fuzz at the same time, one per CPU (each writes only under its own name), so
  # each still gets its FUZZ_SECONDS of a CPU; their reports are printed in order afterwards.
  fz_pids=()
  for h in "${fz_harnesses[@]}"; do
    bash "$REPO_ROOT/tools/fuzz.sh" --no-build --seconds "$FUZZ_SECONDS" "$h" >"$RESULTS_DIR/fuzz-$h.out" 2>&1 &
    fz_pids+=($!)
  done
  for i in "${!fz_harnesses[@]}"; do
    if wait "${fz_pids[$i]}"; then
      fz_passed=$((fz_passed + 1))
    else
      fz_rc=1 fz_failed=$((fz_failed + 1))
    fi
    cat "$RESULTS_DIR/fuzz-${fz_harnesses[$i]}.out"
  done
fi
printf -- '---- done: %s (%ds)\n' "$STEP_NAME" "$((SECONDS - STEP_START))"

# ---- summary -----------------------------------------------------------------------------------
trap - ERR
passed=$((ct_passed + py_passed + san_passed + fz_passed))
failed=$((ct_failed + py_failed + san_failed + fz_failed))
skipped=$((ct_skipped + py_skipped + san_skipped + fz_skipped))
status=0
if [ "$ctest_rc" -ne 0 ] || [ "$py_rc" -ne 0 ] || [ "$san_rc" -ne 0 ] || [ "$fz_rc" -ne 0 ] || [ "$failed" -ne 0 ]; then
  status=1
fi
trap - EXIT
echo
echo "==== Summary: CTest $ct_passed/$ct_failed/$ct_skipped, pytest $py_passed/$py_failed/$py_skipped," \
     "sanitizer CTest $san_passed/$san_failed/$san_skipped, fuzzers $fz_passed/$fz_failed/$fz_skipped" \
     "(passed/failed/skipped): $([ "$status" -eq 0 ] && echo OK || echo FAILED) ===="
# The closing line CI reads: keep it last and alone on its line.
echo "$passed passed, $failed failed, $skipped skipped"
exit "$status"
