#!/usr/bin/env bash
# Fault injection, run by CTest:
#
#   tests/test_faults.sh BIN_DIR LOG_INSPECT SOURCE_DIR BUILD_DIR
#
# Each row writes a faulty copy of data/sample.lcmlog (200 steps) with tools/faults/vislam-faults,
# the fault at step 100, plays it into vislamd with vislam-replay --lockstep inside a private
# network namespace (as tests/test_daemon.sh), records the daemon's outputs with lcm-logger and
# checks: nothing crashed, poses came back for >= 95% of the frames after the fault, and the
# counters (the replay's summary, the daemon's final VISLAM_STATUS) name the fault.
#
# Rows always run (logs, replay, restarts):
#   bad-header   an event whose data length is 0x7fffffff
#   garbage      4 KiB of junk between two events
#   truncate     the log cut inside an event
#   empty, junk-file   an empty log, a log of random bytes
#   restart      kill -9 of the daemon mid-run, a new daemon (no calibration in its config)
#   foreign      a stray process answering every frame with NaN poses on VISLAM_POSE
# Rows of the estimator's own checks (time jumps, new timelines, plausibility, IMU silence):
#   corrupt      10 corrupted copies of events (bit flips, truncation, junk, NaN bytes)
#   imu-hour, imu-max   one IMU sample stamped 1 h ahead, or INT64_MAX
#   imu-min      the first IMU sample stamped INT64_MIN
#   shift        the stream from step 100 on shifted 1 h back
#   twice        the log played twice into one daemon
#   velocity     one IMU sample at 1e300 m/s
#   no-imu       100 steps without IMU (50 to 149)
# Exit 77 (CTest skip) when a private network namespace, lcm-logger or the project's Python is
# unavailable.
set -euo pipefail

SKIP=77
if [ $# -ne 4 ]; then
  echo "usage: $0 BIN_DIR LOG_INSPECT SOURCE_DIR BUILD_DIR" >&2
  exit 2
fi
BIN=$1
INSPECT=$2
SRC=$3
export VISLAM_BUILD_DIR=$4
LOG="$SRC/data/sample.lcmlog"
FAULTS="$SRC/tools/faults/vislam-faults"
export VISLAM_PYTHON="${VISLAM_PYTHON:-${VENV_DIR:-$SRC/.venv}/bin/python}"

if [ -z "${VL_TEST_IN_NETNS:-}" ] && ! "$VISLAM_PYTHON" -c 'import lcm, numpy' 2>/dev/null; then
  echo "SKIP: no Python with the lcm module at $VISLAM_PYTHON (tools/test.sh creates .venv; or set VISLAM_PYTHON)"
  exit $SKIP
fi
# shellcheck source=support/vl_record.sh
source "$(dirname "$0")/support/vl_record.sh"
enter_private_netns "$0" "$@"

# ---- inside the namespace ---------------------------------------------------------------------
begin_netns_test faults

json() { # json FILE KEY -> the value of "KEY": value in a flat JSON summary
  sed -n -E "s/^ *\"$2\": ([^,]*),?$/\1/p" "$1" | head -n 1
}
# at_least_95 GOT OF: GOT >= 95% of OF
at_least_95() { [ $(($1 * 100)) -ge $(($2 * 95)) ] 2>/dev/null || { echo "      $1 of $2 (< 95%)"; return 1; }; }
utime_of_tum_line() { awk '{ split($1, t, "."); printf "%d%06d\n", t[1], t[2] }'; }
crashed() { [ "$1" -ge 128 ] && [ "$1" -ne 124 ]; } # killed by a signal (SIGSEGV 139, SIGABRT 134)

start_logger() { # start_logger NAME: records the daemon's outputs into $OUT/NAME.lcmlog
  record_start "$1" '(VISLAM_POSE|VISLAM_STATUS)'
}
start_daemon() { # start_daemon NAME [ARGS...]: returns once the recording holds one of its statuses
  local name=$1 before
  shift
  before=$("$INSPECT" "$OUT/$name.lcmlog" 2>/dev/null | awk '$1 == "status.count" { print $2 }' || true)
  "$BIN/vislamd" --lcm-url "$URL" --quiet "$@" 2>>"$OUT/$name.daemon.err" &
  DAEMON=$!
  PIDS+=("$DAEMON")
  wait_recorded "$OUT/$name.lcmlog" status.count $((${before:-0} + 1)) 10 || true
}
measured() { # measured NAME: one line of what the row measured
  local j=$OUT/$1.replay.json i=$OUT/$1.inspect
  echo "      measured: replay exit $REPLAY_RC, frames answered $(json "$j" frames_returned)/$(json "$j" frames_expected)," \
    "after the fault $(value "$i" pose.features_after), foreign $(json "$j" poses_foreign)," \
    "log damaged $(json "$j" log_damaged) truncated $(json "$j" log_truncated), restarts $(json "$j" daemon_restarts);" \
    "daemon: imu_in $(value "$i" status.last.imu_in) frames_in $(value "$i" status.last.frames_in)" \
    "rejected $(value "$i" status.last.inputs_rejected) health $(value "$i" status.last.health)"
}
stop_all() { # stop_all NAME [FAULT_UTIME]: SIGTERM to the daemon, the logger stopped, the record inspected
  record_stop "$1"
  DAEMON_RC=$WAIT_RC
  if [ -n "${2:-}" ]; then
    "$INSPECT" "$OUT/$1.lcmlog" --after "$2" >"$OUT/$1.inspect"
  else
    "$INSPECT" "$OUT/$1.lcmlog" >"$OUT/$1.inspect"
  fi
  measured "$1"
}
# Replays need no --wait-for: start_daemon returned once the daemon's status was recorded, so it
# is up and subscribed (and --wait-for would share the rows' short --timeout-ms).
replay() { # replay NAME LOG [ARGS...]: lockstep at 8x; exit status in $REPLAY_RC
  local name=$1 log=$2
  shift 2
  REPLAY_RC=0
  "$BIN/vislam-replay" "$log" --lcm-url "$URL" --lockstep --speed 8 --timeout-ms 1000 \
    --quiet --summary-json "$OUT/$name.replay.json" "$@" 2>"$OUT/$name.replay.err" || REPLAY_RC=$?
}
inject() { # inject FAULT [ARGS...]: $OUT/FAULT.lcmlog; the tool's key=value line into INFO_*
  local fault=$1
  shift
  local line
  line=$("$FAULTS" inject "$LOG" "$OUT/$fault.lcmlog" "$fault" "$@")
  FAULT_UTIME=$(echo "$line" | sed -n -E 's/.*fault_utime=(-?[0-9]+).*/\1/p')
  FRAMES_AFTER=$(echo "$line" | sed -n -E 's/.*frames_after=([0-9]+).*/\1/p')
}

START=$SECONDS
echo "== offline reference: vislam-run"
"$BIN/vislam-run" "$LOG" --trajectory "$OUT/offline.tum" --quiet
FRAMES=$(wc -l <"$OUT/offline.tum")
check "offline trajectory has 200 lines" eq "$FRAMES" 200

# ---- the log readers: vislam-run on each damaged file -----------------------------------------
echo "== damaged logs offline: vislam-run reports, never crashes"
for fault in bad-header garbage truncate empty junk-file; do
  inject "$fault"
  rc=0
  "$BIN/vislam-run" "$OUT/$fault.lcmlog" --trajectory "$OUT/$fault.offline.tum" --quiet 2>"$OUT/$fault.run.err" || rc=$?
  check "vislam-run on $fault: exit 3 (damaged log), no crash" eq "$rc" 3
  check "vislam-run on $fault: says the log is damaged" grep -q 'is damaged' "$OUT/$fault.run.err"
done
check "vislam-run on bad-header: names the offset and the length" \
  grep -q 'offset [0-9]*: data length outside 0..16 MiB.*2147483647' "$OUT/bad-header.run.err"
check "vislam-run on bad-header: every frame still processed (the damaged event was an IMU sample)" \
  eq "$(wc -l <"$OUT/bad-header.offline.tum")" 200
check "vislam-run on truncate: the first 100 frames, and says the log is cut" \
  test "$(wc -l <"$OUT/truncate.offline.tum")" -eq 100 -a -n "$(grep 'cut inside an event' "$OUT/truncate.run.err")"

# ---- row: bad header ---------------------------------------------------------------------------
echo "== row bad-header: an event with data length 0x7fffffff at step 100"
inject bad-header
start_logger bh
start_daemon bh --trajectory "$OUT/bh.tum"
replay bh "$OUT/bad-header.lcmlog"
stop_all bh "$FAULT_UTIME"
check "replay: exit 3 (damaged log), no crash" eq "$REPLAY_RC" 3
check "replay: reports the offset" grep -q 'offset [0-9]*: data length outside' "$OUT/bh.replay.err"
check "replay summary: log_damaged 1, every frame answered" \
  eq "$(json "$OUT/bh.replay.json" log_damaged)/$(json "$OUT/bh.replay.json" frames_missing)" "1/0"
check "daemon exits 0" eq "$DAEMON_RC" 0
check "poses for >= 95% of the frames after the fault" at_least_95 "$(value "$OUT/bh.inspect" pose.features_after)" "$FRAMES_AFTER"
check "final status names it: imu_in 199 (the damaged sample never reached the daemon), frames_in 200" \
  eq "$(value "$OUT/bh.inspect" status.last.imu_in)/$(value "$OUT/bh.inspect" status.last.frames_in)" "199/200"

# ---- row: junk between events ------------------------------------------------------------------
echo "== row garbage: 4 KiB of junk before step 100"
inject garbage
start_logger gb
start_daemon gb
replay gb "$OUT/garbage.lcmlog"
stop_all gb "$FAULT_UTIME"
check "replay: exit 3 (damaged log), no crash" eq "$REPLAY_RC" 3
check "replay summary: log_damaged 1, bytes skipped > 4096" \
  test "$(json "$OUT/gb.replay.json" log_damaged)" = 1 -a "$(json "$OUT/gb.replay.json" log_bytes_skipped)" -gt 4096
check "daemon exits 0" eq "$DAEMON_RC" 0
check "poses for >= 95% of the frames after the fault" at_least_95 "$(value "$OUT/gb.inspect" pose.features_after)" "$FRAMES_AFTER"
check "final status names it: frames_in 199 (the frame before the junk is dropped with it)" \
  eq "$(value "$OUT/gb.inspect" status.last.frames_in)" 199

# ---- row: cut log ------------------------------------------------------------------------------
echo "== row truncate: the log cut inside step 100's frame"
inject truncate
start_logger tr
start_daemon tr
replay tr "$OUT/truncate.lcmlog"
stop_all tr
check "replay: exit 3 (damaged log), no crash" eq "$REPLAY_RC" 3
check "replay summary: log_truncated, every frame before the cut answered" \
  eq "$(json "$OUT/tr.replay.json" log_truncated)/$(json "$OUT/tr.replay.json" frames_returned)" "true/100"
check "replay: says the log is cut" grep -q 'cut inside an event' "$OUT/tr.replay.err"
check "daemon exits 0; final status: 101 imu, 100 frames" \
  eq "$DAEMON_RC/$(value "$OUT/tr.inspect" status.last.imu_in)/$(value "$OUT/tr.inspect" status.last.frames_in)" "0/101/100"

# ---- rows: empty and junk files ----------------------------------------------------------------
echo "== rows empty, junk-file: nothing to play"
for fault in empty junk-file; do
  REPLAY_RC=0
  "$BIN/vislam-replay" "$OUT/$fault.lcmlog" --lcm-url "$URL" --max --quiet --linger-ms 0 \
    --summary-json "$OUT/$fault.replay.json" 2>"$OUT/$fault.replay.err" || REPLAY_RC=$?
  check "replay on $fault: exit 3, no crash, says so" \
    test "$REPLAY_RC" = 3 -a -n "$(grep 'is damaged' "$OUT/$fault.replay.err")"
  check "replay on $fault: no event, nothing sent" \
    eq "$(json "$OUT/$fault.replay.json" log_events)/$(json "$OUT/$fault.replay.json" messages_sent)" "0/0"
done

# ---- row: kill -9 and a restart ----------------------------------------------------------------
echo "== row restart: kill -9 of the daemon at about step 100, then a new daemon (no calibration in its config)"
start_logger rs
start_daemon rs --trajectory "$OUT/rs.tum"
FIRST_DAEMON=$DAEMON
REPLAY_RC=0
"$BIN/vislam-replay" "$LOG" --lcm-url "$URL" --lockstep --speed 4 --timeout-ms 1000 \
  --quiet --summary-json "$OUT/rs.replay.json" 2>"$OUT/rs.replay.err" &
REPLAY=$!
PIDS+=("$REPLAY")
for ((i = 0; i < 200; i++)); do
  [ -f "$OUT/rs.tum" ] && [ "$(wc -l <"$OUT/rs.tum")" -ge 100 ] && break
  sleep 0.05
done
kill -KILL "$FIRST_DAEMON"
wait_exit "$FIRST_DAEMON" 5
LINES_A=$(wc -l <"$OUT/rs.tum")
KILL_UTIME=$(tail -n 1 "$OUT/rs.tum" | utime_of_tum_line)
echo "      killed after $LINES_A frames"
start_daemon rs --trajectory "$OUT/rs.tum"
wait_exit "$REPLAY" 60
REPLAY_RC=$WAIT_RC
stop_all rs "$KILL_UTIME"
AFTER=$((FRAMES - LINES_A))
check "the first daemon's trajectory is kept: its $LINES_A lines are the offline run's first lines" \
  cmp <(head -n "$LINES_A" "$OUT/rs.tum") <(head -n "$LINES_A" "$OUT/offline.tum")
check "then one '#' line marks the new run" eq "$(sed -n "$((LINES_A + 1))p" "$OUT/rs.tum" | cut -c1)" "#"
check "the new daemon tracks: poses for >= 95% of the $AFTER frames after the kill" \
  at_least_95 "$(value "$OUT/rs.inspect" pose.features_after)" "$AFTER"
check "its trajectory has them too" at_least_95 "$(($(wc -l <"$OUT/rs.tum") - LINES_A - 1))" "$AFTER"
check "replay summary names it: daemon_restarts 1, the calibration re-published" \
  test "$(json "$OUT/rs.replay.json" daemon_restarts)" = 1 -a "$(json "$OUT/rs.replay.json" calibrations_resent)" -ge 1
check "replay: no crash; at most 3 frames missing (the kill), no foreign pose" \
  test "$REPLAY_RC" -le 1 -a "$(json "$OUT/rs.replay.json" frames_missing)" -le 3 \
  -a "$(json "$OUT/rs.replay.json" poses_foreign)" = 0
check "new daemon exits 0; its final status: calibrated (health bit 1 clear), frames_in >= $((AFTER * 95 / 100))" \
  test "$DAEMON_RC" = 0 -a $(($(value "$OUT/rs.inspect" status.last.health) & 1)) = 0 \
  -a "$(value "$OUT/rs.inspect" status.last.frames_in)" -ge $((AFTER * 95 / 100))

# ---- row: a foreign process answering NaN poses --------------------------------------------------
echo "== row foreign: a stray process answers every frame with NaN poses on VISLAM_POSE"
"$FAULTS" foreign-poses --lcm-url "$URL" --seconds 30 >"$OUT/fp.foreign.out" 2>&1 &
FOREIGN=$!
PIDS+=("$FOREIGN")
check "the stray process listens before the replay starts" wait_line "$OUT/fp.foreign.out" "listening" 30
start_logger fp
start_daemon fp --trajectory "$OUT/fp.tum"
replay fp "$LOG"
stop_all fp
kill -INT "$FOREIGN" 2>/dev/null || true
wait_exit "$FOREIGN" 5
check "replay: exit 1 (foreign poses), not 0" eq "$REPLAY_RC" 1
check "replay summary: the daemon's 400 poses accepted, every frame answered" \
  eq "$(json "$OUT/fp.replay.json" poses_accepted)/$(json "$OUT/fp.replay.json" frames_returned)" "400/200"
check "replay summary names it: >= 200 foreign poses, >= 200 of them non-finite" \
  test "$(json "$OUT/fp.replay.json" poses_foreign)" -ge 200 -a "$(json "$OUT/fp.replay.json" poses_non_finite)" -ge 200
check "replay: reports them" grep -q 'foreign pose' "$OUT/fp.replay.err"
check "daemon exits 0, its trajectory equals vislam-run's (undisturbed)" \
  test "$DAEMON_RC" = 0 -a -z "$(cmp "$OUT/fp.tum" "$OUT/offline.tum" 2>&1)"

# ---- the estimator's rows ---------------------------------------------------------------------
# fault:step:count:the final status counter that must name it
core_rows="corrupt:100::inputs_rejected imu-hour:100::time_jumps imu-max:100::time_jumps
  imu-min:0::timeline_changes shift:100::timeline_changes twice:100::timeline_changes
  velocity:100::imu_implausible no-imu:50:100:frames_imu_silent"
for row in $core_rows; do
  IFS=: read -r fault step count counter <<<"$row"
  echo "== row $fault (estimator)"
  if [ -n "$count" ]; then inject "$fault" --step "$step" --count "$count"; else inject "$fault" --step "$step"; fi
  start_logger "c-$fault"
  start_daemon "c-$fault"
  # Never give up: whether the daemon comes back after the fault is the question.
  replay "c-$fault" "$OUT/$fault.lcmlog" --timeout-ms 200 --max-timeouts 0
  case $fault in
    twice) # the second pass, all of it
      stop_all "c-$fault"
      got=$(value "$OUT/c-$fault.inspect" pose.features)
      want=$((2 * FRAMES)) ;;
    shift) # the frames after the fault live an hour earlier: all frames minus those before it
      stop_all "c-$fault"
      got=$(($(value "$OUT/c-$fault.inspect" pose.features) - (FRAMES - FRAMES_AFTER)))
      want=$FRAMES_AFTER ;;
    *)
      stop_all "c-$fault" "$FAULT_UTIME"
      got=$(value "$OUT/c-$fault.inspect" pose.features_after)
      want=$FRAMES_AFTER ;;
  esac
  check "$fault: replay and daemon do not crash; daemon exits 0" \
    test "$DAEMON_RC" = 0 -a "$REPLAY_RC" -lt 128
  check "$fault: poses for >= 95% of the frames after the fault ($got of $want)" at_least_95 "$got" "$want"
  check "$fault: no non-finite pose published" eq "$(value "$OUT/c-$fault.inspect" pose.non_finite)" 0
  check "$fault: the final status names it ($counter >= 1)" ge "$(value "$OUT/c-$fault.inspect" "status.last.$counter")" 1
done

echo "== $((SECONDS - START)) s, $FAILS failure(s)"
[ "$FAILS" -eq 0 ]
