#!/bin/bash
# vislamd --supersede-imu-poses (and --warm-us), end to end in a private network namespace. The
# daemon is stopped (SIGSTOP) while a short log is played, so every input is queued on its socket
# before it reads the first: each IMU sample then has its frame waiting behind it, whatever the
# machine's timing, and the counts are exact.
#   - every IMU pose with its frame behind it is superseded: not sent, counted in the summary;
#     only frame poses go out, and the trajectory is vislam-run's, byte for byte;
#   - a frame that gives no pose (here one whose payload does not decode, inserted after step 3's
#     IMU sample) does not take its IMU pose with it: that pose is sent after it, counted as late;
#   - an IMU sample that comes when a frame is due (the frame period known) but has none behind it
#     (step 5's frame removed) holds its pose for it; the next sample's pose sends it, counted late;
#   - the session still counts every pose it handed out (status poses_out).
set -uo pipefail

if [ $# -ne 3 ]; then
  echo "usage: $0 BIN_DIR LOG_INSPECT SOURCE_DIR" >&2
  exit 2
fi
BIN=$1
INSPECT=$2
SRC=$3
# Python (the log's bad frame is written with vislam_tools.faults), as test_faults.sh finds it.
PY="${VISLAM_PYTHON:-${VENV_DIR:-$SRC/.venv}/bin/python}"
if [ -z "${VL_TEST_IN_NETNS:-}" ] && ! "$PY" -c 'import lcm' 2>/dev/null; then
  echo "SKIP: no Python with the lcm module at $PY (tools/test.sh creates .venv; or set VISLAM_PYTHON)"
  exit 77
fi

source "$(dirname "$0")/support/vl_record.sh"
enter_private_netns "$0" "$@"
begin_netns_test supersede
START=$SECONDS
STEPS=8

echo "== the options"
"$BIN/vislamd" --warm-us 50001 2>/dev/null
check "vislamd --warm-us above 50000: a usage error (2)" eq $? 2
"$BIN/vislamd" --warm-us -1 2>/dev/null
check "vislamd --warm-us -1: a usage error (2)" eq $? 2
"$BIN/vislamd" --warm-us 1000 --supersede-imu-poses --print-config >/dev/null
check "vislamd --warm-us 1000 --supersede-imu-poses: accepted" eq $? 0
"$BIN/vislam-latency" "$SRC/data/sample.lcmlog" --warm-us x 2>/dev/null
check "vislam-latency --warm-us x: a usage error (2)" eq $? 2
# Into a file, not a pipe: grep -q would leave before a help text over one buffer (4 KiB) is
# written, and the program's SIGPIPE would fail the pipeline.
"$BIN/vislam-latency" --help >"$OUT/latency.help"
check "vislam-latency --help names --supersede-imu-poses" grep -q -- "--supersede-imu-poses" "$OUT/latency.help"
"$BIN/vislamd" --keep-awake 2>"$OUT/awake.err"
check "vislamd --keep-awake without --cpu: a usage error (2)" eq $? 2
check "vislamd --keep-awake without --cpu: says it needs --cpu" grep -q -- '--keep-awake needs --cpu' "$OUT/awake.err"
"$BIN/vislamd" --keep-awake --cpu 0 --print-config >/dev/null
check "vislamd --keep-awake --cpu 0: accepted" eq $? 0
check "vislam-latency --help names --keep-awake" grep -q -- "--keep-awake" "$OUT/latency.help"

"$BIN/vislam-sim" --out "$OUT/small.lcmlog" --truth "$OUT/small.tum" --steps "$STEPS" --max-observations 60 2>/dev/null
check "vislam-sim writes an $STEPS-step log" eq $? 0
"$BIN/vislam-run" "$OUT/small.lcmlog" --trajectory "$OUT/offline.tum" --quiet
check "vislam-run: one line per frame" eq "$(wc -l <"$OUT/offline.tum")" "$STEPS"
# The same log with an undecodable frame (its fingerprint and utime, then cut) after step 3's IMU sample.
PYTHONPATH="$SRC/tools" "$PY" - "$OUT/small.lcmlog" "$OUT/junk.lcmlog" "$OUT/missing.lcmlog" <<'PYEOF'
import sys
from vislam_tools import faults
events = faults.read_log(sys.argv[1])
imu = faults.step_indices(events, "VISLAM_IMU")[3]
frame = faults.frame_after(events, imu, "VISLAM_FEATURES")
junk = faults.Event(0, events[frame].timestamp, "VISLAM_FEATURES", events[frame].data[:20])
events.insert(imu + 1, junk)
for n, e in enumerate(events):
    e.number = n
faults.write_log(sys.argv[2], [e.encode() for e in events])
# The same log without step 5's frame: its IMU sample comes when a frame is due, and none follows.
events = faults.read_log(sys.argv[1])
imu = faults.step_indices(events, "VISLAM_IMU")[5]
del events[faults.frame_after(events, imu, "VISLAM_FEATURES")]
for n, e in enumerate(events):
    e.number = n
faults.write_log(sys.argv[3], [e.encode() for e in events])
PYEOF
check "the logs with an undecodable frame and without a frame written" eq $? 0
"$BIN/vislam-run" "$OUT/missing.lcmlog" --trajectory "$OUT/missing.offline.tum" --quiet

# run NAME LOG FRAMES: vislamd (stopped) with both options, LOG (FRAMES frames) played into its
# socket, then resumed.
run() {
  local name=$1 log=$2 frames=$3
  start_recording_daemon "$name" "$BIN/vislamd" --lcm-url "$URL" --trajectory "$OUT/$name.tum" \
    --supersede-imu-poses --warm-us 1000
  kill -STOP "$DAEMON"
  "$BIN/vislam-replay" "$log" --lcm-url "$URL" --speed 50 --calib-period-ms 0 --quiet 2>"$OUT/$name.replay.err"
  check "$name: the replay played the log" eq $? 0
  kill -CONT "$DAEMON"
  wait_recorded "$OUT/$name.lcmlog" status.last.frames_in "$frames" 10
  record_stop "$name"
  check "$name: vislamd exits 0 on SIGTERM" eq "$WAIT_RC" 0
  "$INSPECT" "$OUT/$name.lcmlog" >"$OUT/$name.inspect"
}
start_recording_daemon() {
  local name=$1
  shift
  record_start "$name" '(VISLAM_POSE|VISLAM_STATUS)'
  "$@" 2>"$OUT/$name.daemon.err" &
  DAEMON=$!
  PIDS+=("$DAEMON")
  wait_recorded "$OUT/$name.lcmlog" status.count 1 10
}

echo "== every IMU sample's frame queued behind it"
run a "$OUT/small.lcmlog" "$STEPS"
A=$OUT/a.inspect
check "only the frames' poses sent ($STEPS features, 0 imu)" \
  eq "$(value "$A" pose.count)/$(value "$A" pose.imu)/$(value "$A" pose.features)" "$STEPS/0/$STEPS"
check "the summary counts them: $STEPS superseded, 0 late" \
  grep -q "superseded IMU poses: $STEPS not sent .*, 0 held and sent late" "$OUT/a.daemon.err"
check "the session handed out every pose (status poses_out $((2 * STEPS)))" eq "$(value "$A" status.last.poses_out)" $((2 * STEPS))
check "the trajectory is vislam-run's" cmp "$OUT/a.tum" "$OUT/offline.tum"
check "--warm-us: its costs in the summary" grep -q "warm (--warm-us 1000): .* frame periods, frame period [0-9]* us; reading the state" \
  "$OUT/a.daemon.err"

echo "== step 3's IMU sample followed by an undecodable frame"
run b "$OUT/junk.lcmlog" $((STEPS + 1))
B=$OUT/b.inspect
check "step 3's IMU pose sent after the bad frame, the others superseded ($((STEPS + 1)) poses: 1 imu)" \
  eq "$(value "$B" pose.count)/$(value "$B" pose.imu)/$(value "$B" pose.features)" "$((STEPS + 1))/1/$STEPS"
check "the summary counts them: $((STEPS - 1)) superseded, 1 late" \
  grep -q "superseded IMU poses: $((STEPS - 1)) not sent .*, 1 held and sent late" "$OUT/b.daemon.err"
check "the bad frame counted as a decode error" grep -q "decode_errors 1" "$OUT/b.daemon.err"
check "the trajectory is vislam-run's" cmp "$OUT/b.tum" "$OUT/offline.tum"

echo "== step 5's frame missing: its IMU pose held for it (a frame is due), sent when the next sample comes"
run c "$OUT/missing.lcmlog" $((STEPS - 1))
C=$OUT/c.inspect
check "step 5's IMU pose sent, the others superseded ($STEPS poses: 1 imu)" \
  eq "$(value "$C" pose.count)/$(value "$C" pose.imu)/$(value "$C" pose.features)" "$STEPS/1/$((STEPS - 1))"
check "the summary counts them: $((STEPS - 1)) superseded, 1 late" \
  grep -q "superseded IMU poses: $((STEPS - 1)) not sent .*, 1 held and sent late" "$OUT/c.daemon.err"
check "the trajectory is vislam-run's on the same log" cmp "$OUT/c.tum" "$OUT/missing.offline.tum"

echo "== $((SECONDS - START)) s, $FAILS failure(s)"
[ "$FAILS" -eq 0 ]
