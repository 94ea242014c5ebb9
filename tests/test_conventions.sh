#!/usr/bin/env bash
# The command-line conventions of the C programs (platform/vl_cli.h), run by CTest:
#
#   tests/test_conventions.sh BIN_DIR SOURCE_DIR
#
# --version in every program: one line "PROGRAM VERSION[ (git DESCRIPTION)]" with the project
# version of CMakeLists.txt, the same in all. --print-config: vislamd prints the same INI as
# vislam-run (defaults and a config file), numbers in shortest form. A reader that went away:
# --version and --print-config into a pipe nobody reads end without a word on stderr and with a
# non-zero status, whether SIGPIPE kills them (default) or is ignored (then the write error is
# theirs). vislam-sim names an unknown option.
# No -e: every check runs and is reported; the exit status counts the failed ones.
set -uo pipefail

if [ $# -ne 2 ]; then
  echo "usage: $0 BIN_DIR SOURCE_DIR" >&2
  exit 2
fi
BIN=$1
SRC=$2
source "$(dirname "$0")/support/vl_record.sh" # check, eq, ge
OUT=$(mktemp -d /tmp/vislam_test_conventions.XXXXXX)
trap 'rm -rf "$OUT"' EXIT
FAILS=0
PROGRAMS=(vislam-run vislamd vislam-replay vislam-sim vislam-latency)

PROJECT_VERSION=$(sed -n 's/^project(vislam VERSION \([^ )]*\).*/\1/p' "$SRC/CMakeLists.txt")
VERSION=""
for p in "${PROGRAMS[@]}"; do
  line=$("$BIN/$p" --version)
  check "$p --version exits 0: '$line'" eq $? 0
  check "$p --version is 'PROGRAM $PROJECT_VERSION[ (git ...)]'" \
    grep -qxE "$p ${PROJECT_VERSION//./\\.}( \(git [0-9A-Za-z._-]+\))?" <<<"$line"
  VERSION=${VERSION:-${line#"$p "}}
  check "$p: the same version as the others" eq "${line#"$p "}" "$VERSION"
done

"$BIN/vislam-run" --print-config >"$OUT/run.ini"
"$BIN/vislamd" --print-config >"$OUT/vislamd.ini"
check "vislamd --print-config equals vislam-run's (defaults)" cmp "$OUT/vislamd.ini" "$OUT/run.ini"
check "numbers in shortest form (angular_velocity = 0.05, no 16-digit run)" \
  eq "$(grep -c '^angular_velocity = 0.05$' "$OUT/run.ini")/$(grep -cE '[0-9]{16}' "$OUT/run.ini")" "1/0"
printf '[noise]\npixel = 0.3\nlinear_velocity = 0.1\n[landmarks]\nmax_landmarks = 64\n' >"$OUT/c.ini"
"$BIN/vislam-run" --config "$OUT/c.ini" --print-config >"$OUT/run.c.ini"
"$BIN/vislamd" --config "$OUT/c.ini" --print-config >"$OUT/vislamd.c.ini"
check "vislamd --print-config equals vislam-run's (a config file)" cmp "$OUT/vislamd.c.ini" "$OUT/run.c.ini"
check "the config file's values printed as written" \
  eq "$(grep -cxE 'pixel = 0.3|linear_velocity = 0.1|max_landmarks = 64' "$OUT/run.c.ini")" 3

# closed_pipe IGNORE PROGRAM ARGS...: runs PROGRAM once the reader of its stdout has gone (the
# reader, `true`, ends at once; the program starts 0.1 s later), with SIGPIPE ignored if IGNORE
# is 1. Its exit status in $RC, its stderr in $OUT/pipe.err.
closed_pipe() {
  local ignore=$1
  shift
  (
    sleep 0.1 # the reader ends meanwhile: the program's first write finds no reader
    [ "$ignore" = 1 ] && trap '' PIPE
    "$@" 2>"$OUT/pipe.err"
    echo $? >"$OUT/pipe.rc"
  ) | true
  RC=$(cat "$OUT/pipe.rc")
}
for ignore in 0 1; do
  what=$([ "$ignore" = 1 ] && echo "SIGPIPE ignored" || echo "SIGPIPE default")
  for cmd in "vislam-run --print-config" "vislamd --print-config" "vislam-run --version" "vislamd --version" \
    "vislam-replay --version" "vislam-sim --version"; do
    read -r -a argv <<<"$cmd"
    closed_pipe "$ignore" "$BIN/${argv[0]}" "${argv[@]:1}"
    check "$cmd into a closed pipe ($what): non-zero ($RC), nothing on stderr" \
      test "$RC" -ne 0 -a ! -s "$OUT/pipe.err"
  done
done

"$BIN/vislam-sim" --bogus 2>"$OUT/sim.err"
check "vislam-sim --bogus: usage error (2)" eq $? 2
check "vislam-sim names the unknown option" grep -q 'unknown option --bogus' "$OUT/sim.err"
"$BIN/vislam-sim" --steps 2>"$OUT/sim.err"
check "vislam-sim --steps without a value: says so" grep -q -- '--steps needs a value' "$OUT/sim.err"

echo "== $FAILS failure(s)"
[ "$FAILS" -eq 0 ]
