#!/usr/bin/env bash
# Builds the libFuzzer harnesses of tests/fuzz (clang, -DVL_FUZZ=ON) and runs each for a bounded time.
#
#   tools/fuzz.sh [--seconds N] [--build-dir DIR] [--no-build] [--build-only] [HARNESS...]
#
# HARNESS is messages or log_reader (default: both, one after the other). Each runs on its seed
# corpus (made from data/sample.lcmlog by the build) plus a working corpus that persists in the
# build directory, so local runs pick up where the last one stopped. A crash stops that harness;
# the input is written to DIR/fuzz-artifacts/HARNESS/ and printed (base64 when small), with the
# command that replays it. Exit 0 when no harness crashed, 1 when one did, 2 on a usage or build error.
#
# Options and environment (all optional):
#   --seconds N / VL_FUZZ_SECONDS   run time per harness (default 60)
#   --build-dir DIR / FUZZ_BUILD_DIR build directory (default build-fuzz, relative to the repo root)
#   --no-build                      use the harnesses already built in DIR
#   --build-only                    configure and build, run nothing
#   JOBS                            build parallelism (default 2)
#   UNITY_ROOT, VL_SKIP_APT         as for tools/test.sh (the build configures the tests too)
#   VL_FUZZ_CHECK_FINITE=0          fuzz_messages does not check the published pose for NaN/inf
#   VL_FUZZ_TIMEOUT                 seconds one input may take before it counts as a hang (default 30)
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$REPO_ROOT"
export VL_REPO_ROOT="$REPO_ROOT"

ALL_HARNESSES=(messages log_reader)
SECONDS_EACH="${VL_FUZZ_SECONDS:-60}"
BUILD_DIR="${FUZZ_BUILD_DIR:-build-fuzz}"
DO_BUILD=1
DO_RUN=1
HARNESSES=()

usage() { sed -n '2,22p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; }

while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) SECONDS_EACH="${2:?--seconds needs a value}"; shift 2 ;;
    --build-dir) BUILD_DIR="${2:?--build-dir needs a value}"; shift 2 ;;
    --no-build) DO_BUILD=0; shift ;;
    --build-only) DO_RUN=0; shift ;;
    -h|--help) usage; exit 0 ;;
    messages|log_reader) HARNESSES+=("$1"); shift ;;
    *) echo "tools/fuzz.sh: unknown argument: $1" >&2; usage >&2; exit 2 ;;
  esac
done
if [ ${#HARNESSES[@]} -eq 0 ]; then HARNESSES=("${ALL_HARNESSES[@]}"); fi
case "$SECONDS_EACH" in ''|*[!0-9]*) echo "tools/fuzz.sh: --seconds must be a whole number" >&2; exit 2 ;; esac
case "$BUILD_DIR" in /*) ;; *) BUILD_DIR="$REPO_ROOT/$BUILD_DIR" ;; esac
TIMEOUT_EACH="${VL_FUZZ_TIMEOUT:-30}"

if [ "$DO_BUILD" = 1 ]; then
  if ! command -v clang >/dev/null 2>&1 || ! command -v clang++ >/dev/null 2>&1; then
    echo "tools/fuzz.sh: clang not found (tools/setup.sh installs it: clang, libclang-rt-14-dev)" >&2
    exit 2
  fi
  # shellcheck source=tools/setup.sh
  source "$REPO_ROOT/tools/setup.sh"
  vl_setup_unity
  CC=clang CXX=clang++ cmake -S "$REPO_ROOT" -B "$BUILD_DIR" -DCMAKE_BUILD_TYPE=Release -DVL_WERROR=ON \
    -DVL_FUZZ=ON -DUNITY_ROOT="$VL_UNITY_ROOT" >/dev/null
  targets=(vl_fuzz_seeds)
  for h in "${HARNESSES[@]}"; do targets+=("fuzz_$h"); done
  cmake --build "$BUILD_DIR" -j "${JOBS:-2}" --target "${targets[@]}"
fi
[ "$DO_RUN" = 1 ] || exit 0

crashed=0
for h in "${HARNESSES[@]}"; do
  bin="$BUILD_DIR/bin/fuzz_$h"
  seeds="$BUILD_DIR/fuzz-seeds/$h"
  corpus="$BUILD_DIR/fuzz-corpus/$h"
  artifacts="$BUILD_DIR/fuzz-artifacts/$h"
  log="$BUILD_DIR/fuzz-logs/$h.log"
  if [ ! -x "$bin" ] || [ ! -d "$seeds" ]; then
    echo "tools/fuzz.sh: $bin or $seeds missing (build first, without --no-build)" >&2
    exit 2
  fi
  if [ "$SECONDS_EACH" -eq 0 ]; then
    echo "fuzz_$h: skipped (0 seconds)"
    continue
  fi
  mkdir -p "$corpus" "$artifacts" "$(dirname "$log")"
  echo "fuzz_$h: ${SECONDS_EACH}s on $(find "$seeds" -type f | wc -l) seeds + $(find "$corpus" -type f | wc -l) corpus inputs (log: $log)"
  rc=0
  # The harnesses' libraries print to stderr on every bad input: the full output goes to the log.
  timeout --kill-after=10 $((SECONDS_EACH + 120)) "$bin" -max_total_time="$SECONDS_EACH" \
    -timeout="$TIMEOUT_EACH" -print_final_stats=1 -dict="$REPO_ROOT/tests/fuzz/$h.dict" \
    -artifact_prefix="$artifacts/" "$corpus" "$seeds" </dev/null >"$log" 2>&1 || rc=$?
  grep -E '^#[0-9]+[[:space:]]+DONE|^stat::number_of_executed_units|^stat::peak_rss_mb' "$log" | sed 's/^/    /' || true
  if [ "$rc" -eq 0 ]; then
    echo "fuzz_$h: ok, no crash"
    continue
  fi
  crashed=1
  echo "fuzz_$h: CRASHED (exit $rc); its report:"
  # From the first line of the report (the harness's own message, a sanitizer's or libFuzzer's)
  # to the end; the libraries' complaints about bad inputs before it are only in the log.
  awk 'on || /^fuzz_[a-z_]+: |^==[0-9]+==|ERROR: libFuzzer|^[^ ]+:[0-9]+:[0-9]+: runtime error/ { on = 1; print }' "$log" \
    | grep -v -E '^#[0-9]+[[:space:]]+(NEW|REDUCE|pulse)|^[[:space:]]+NEW_FUNC' | head -n 60 | sed 's/^/    /'
  unit="$(sed -n 's/.*Test unit written to \(.*\)$/\1/p' "$log" | tail -n 1)"
  if [ -n "$unit" ] && [ -f "$unit" ]; then
    echo "fuzz_$h: crash input: $unit ($(wc -c <"$unit") bytes)"
    echo "    replay: build/bin/vl_fuzz_replay_$h $unit    (or $bin $unit)"
    echo "    record: copy it to tests/fuzz/regressions/$h/ (tests/fuzz/known/$h/ while unfixed), with a note"
    if [ "$(wc -c <"$unit")" -le 16384 ]; then
      echo "    base64: $(base64 -w0 "$unit")"
    fi
  elif [ "$rc" -eq 124 ] || [ "$rc" -eq 137 ]; then
    echo "fuzz_$h: did not stop in time (killed); see $log"
  else
    echo "fuzz_$h: no crash input was written; see $log"
  fi
done
exit "$crashed"
