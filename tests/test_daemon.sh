#!/usr/bin/env bash
# Integration test of vislamd and vislam-replay, run by CTest:
#
#   tests/test_daemon.sh BIN_DIR ALLOC_COUNTER_SO LOG_INSPECT SOURCE_DIR
#
# Runs inside a private network namespace (unshare --net, loopback with a multicast
# route, udpm with ttl=0), so it neither needs nor disturbs the host's LCM traffic.
# Checks:
#   1. counts: every IMU sample and frame of data/sample.lcmlog gives one VISLAM_POSE and one
#      POSE; the status messages' contents are consistent (decoded from an lcm-logger log).
#   2. equivalence: the daemon's trajectory under a --lockstep replay is byte-identical to
#      vislam-run's on the same log; its --step-samples hold one line per frame, in the
#      trajectory's order, each with a positive step time (ns); its map (VISLAM_LANDMARKS, the
#      window flushed at exit included), written as a PLY, is byte-identical to vislam-run --map's,
#      in well-formed batches numbered in order, as many landmarks as the final status' mapped.
#   3. SIGTERM mid-run: exit 0, the trajectory is a complete prefix of the offline one ending
#      at the last frame whose pose was published, and a final status was published.
#   4. heap allocations after start-up (LD_PRELOAD counter, reporting to its own file; the
#      daemon keeps --step-samples and writes them at exit): none in the main thread, and none
#      in the whole process (it reads the socket itself: liblcm starts no receive thread).
#      An empty ALLOC_COUNTER_SO (sanitizer builds: ASan owns malloc) skips this check.
#   5. calibration from the config file alone (no VISLAM_CALIB on the wire): the daemon estimates,
#      and equals vislam-run with the same config.
#   6. the same log replayed twice into one daemon: the second pass is a new timeline,
#      the daemon re-initializes within a few inputs, says so in VISLAM_STATUS, and tracks again;
#      the map's batches of the second pass are in world 1.
#   7. a recording of run A by lcm-logger (inputs and the daemon's outputs) replayed: by default
#      only the inputs go out, the recorded poses and statuses are skipped and counted;
#      --all-channels sends them too (and the replay's own pose subscription receives them).
#   8. --stats-json: the daemon's summary as JSON: its step counts and percentiles, its receiver's
#      counts, its map count, and core counters equal to vislam-run --stats-json's on the same log;
#      tools/bench.sh's daemon table reads it.
# Synchronization waits on what the daemon publishes (its statuses, read back from the recording
# or awaited by vislam-replay --wait-for), never on fixed delays; every number checked comes from
# recorded messages, the replay's JSON summary, the daemon's --stats-json, the trajectory files or
# the allocation counter's own report, never from the daemon's stderr.
# Exit 77 (CTest skip) when a private network namespace or lcm-logger is unavailable.
# No -e: every check runs and is reported; the exit status counts the failed ones.
set -uo pipefail

SKIP=77
if [ $# -ne 4 ]; then
  echo "usage: $0 BIN_DIR ALLOC_COUNTER_SO LOG_INSPECT SOURCE_DIR" >&2
  exit 2
fi
BIN=$1
ALLOC_SO=$2
INSPECT=$3
SRC=$4
LOG="$SRC/data/sample.lcmlog"
PYTHON=${VISLAM_PYTHON:-python3}

# shellcheck source=support/vl_record.sh
source "$(dirname "$0")/support/vl_record.sh"
enter_private_netns "$0" "$@"

# ---- inside the namespace ---------------------------------------------------------------------
begin_netns_test daemon



# start_recording NAME CHANNELS ERR -- COMMAND...: lcm-logger into $OUT/NAME.lcmlog, then the daemon
# COMMAND with its stderr into ERR.
# Returns once the recording holds one of the daemon's statuses: the logger is subscribed and the
# daemon is up and subscribed, before any input is sent (so replays after it need no --wait-for,
# which would wait for the next periodic status).
start_recording() {
  local name=$1 channels=$2 err=$3
  shift 4
  record_start "$name" "$channels"
  "$@" 2>"$err" &
  DAEMON=$!
  PIDS+=("$DAEMON")
  # The daemon publishes a status at start-up and once a second: one second and a bit covers a
  # logger that subscribed just after the first.
  wait_recorded "$OUT/$name.lcmlog" status.count 1 10
}
START=$SECONDS
echo "== offline reference: vislam-run"
"$BIN/vislam-run" "$LOG" --trajectory "$OUT/offline.tum" --map "$OUT/offline.ply" --stats-json "$OUT/offline.stats.json" --quiet
check "vislam-run succeeds" eq $? 0
FRAMES=$(wc -l <"$OUT/offline.tum")
check "offline trajectory has 200 lines" eq "$FRAMES" 200
LAST_UTIME=$(tail -n 1 "$OUT/offline.tum" | awk '{ split($1, t, "."); printf "%d%06d\n", t[1], t[2] }')

# ---- run A: full lockstep replay at 4x ---------------------------------------------------------
echo "== run A: vislamd + vislam-replay --lockstep --speed 4"
start_recording a '(VISLAM_IMU|VISLAM_FEATURES|VISLAM_CALIB|VISLAM_POSE|POSE|VISLAM_STATUS|VISLAM_LANDMARKS)' "$OUT/a.daemon.err" -- \
  env VL_ALLOC_REPORT="$OUT/a.alloc" ${ALLOC_SO:+LD_PRELOAD="$ALLOC_SO"} "$BIN/vislamd" --lcm-url "$URL" --trajectory "$OUT/a.tum" \
  --step-samples "$OUT/a.steps" --stats-json "$OUT/a.stats.json"
check "run A: the daemon's first status recorded before any input" eq $? 0
"$BIN/vislam-replay" "$LOG" --lcm-url "$URL" --lockstep --speed 4 --timeout-ms 5000 \
  --summary-json "$OUT/a.replay.json" 2>"$OUT/a.replay.err"
check "replay A exits 0 (every frame's pose came back)" eq $? 0
record_stop a
check "daemon A exits 0 on SIGTERM" eq "$WAIT_RC" 0
"$INSPECT" "$OUT/a.lcmlog" --map-out "$OUT/a.map.ply" >"$OUT/a.inspect"
sed 's/^/      /' "$OUT/a.replay.err" | grep -v '^\s*$'
grep -E 'step latency|all steps|propagation|update  ' "$OUT/a.daemon.err" | sed 's/^/      /'
sed 's/^/      /' "$OUT/a.alloc"

# (1) counts in = counts out
A=$OUT/a.inspect
check "VISLAM_POSE: 400 poses (200 imu + 200 features)" eq "$(value "$A" pose.count)/$(value "$A" pose.imu)/$(value "$A" pose.features)" "400/200/200"
check "VISLAM_POSE sequence numbers 0..399 in order" eq "$(value "$A" pose.sequence_ok)" 1
check "POSE (bot_core.pose_t): one per VISLAM_POSE, same utime and position" eq "$(value "$A" bot.count)/$(value "$A" bot.matches_pose)" "400/1"
check "no undecodable message" eq "$(value "$A" pose.decode_errors)/$(value "$A" bot.decode_errors)/$(value "$A" status.decode_errors)" "0/0/0"
check "replay counted 400 poses" grep -q '"poses_received": 400' "$OUT/a.replay.json"
# the daemon's --stats-json, flattened to "key value" lines (nested keys joined by dots)
"$PYTHON" - "$OUT/a.stats.json" "$OUT/offline.stats.json" >"$OUT/a.stats" <<'PY'
import json, sys
daemon, offline = (json.load(open(p)) for p in sys.argv[1:3])
def flat(d, prefix=""):
    for k, v in d.items():
        if isinstance(v, dict):
            yield from flat(v, prefix + k + ".")
        else:
            yield prefix + k, v
for k, v in flat(daemon):
    print(k, v)
print("core_counters_equal_offline", int(daemon["core_counters"] == offline["core_counters"]))
PY
check "--stats-json written and parsed" eq $? 0
J=$OUT/a.stats
check "daemon A's receiver (--stats-json): every input handed on, nothing dropped" \
  test "$(value "$J" daemon.lcm_rx_messages)" -ge 400 -a "$(value "$J" daemon.lcm_rx_fragments_dropped)/$(value "$J" daemon.lcm_rx_malformed)" = "0/0"
check "status published at least twice, wall-clock utime increasing" test "$(value "$A" status.count)" -ge 2 -a "$(value "$A" status.utime_increasing)" = 1
check "first status: waiting for calibration" eq "$(value "$A" status.first.health)" 1
check "final status: imu_in 200, frames_in 200, poses_out 400, rejected 0, steps 400" \
  eq "$(value "$A" status.last.imu_in)/$(value "$A" status.last.frames_in)/$(value "$A" status.last.poses_out)/$(value "$A" status.last.inputs_rejected)/$(value "$A" status.last.steps)" "200/200/400/0/400"
check "final status: last_input_utime is the last frame's" eq "$(value "$A" status.last.last_input_utime)" "$LAST_UTIME"
check "final status: window capacity 128, the window flushed to the map at exit (0 left), landmarks mapped > 0" \
  test "$(value "$A" status.last.window_capacity)" = 128 -a "$(value "$A" status.last.window_landmarks)" = 0 \
  -a "$(value "$A" status.last.landmarks_mapped)" -gt 0
check "final status: the noise in use is published (positive)" awk -v a="$(value "$A" status.last.linear_velocity_noise)" \
  -v b="$(value "$A" status.last.angular_velocity_noise)" -v c="$(value "$A" status.last.pixel_noise)" 'BEGIN { exit !(a > 0 && b > 0 && c > 0) }'
check "final status: observations gated > 0 (the sample has outliers)" test "$(value "$A" status.last.observations_gated)" -gt 0
check "final status: budget = sensor period (99..109 ms)" \
  test "$(value "$A" status.last.budget_us)" -ge 99000 -a "$(value "$A" status.last.budget_us)" -le 109000
check "final status: 0 < p50 <= p99 <= p99.9 <= max" \
  test 0 -lt "$(value "$A" status.last.latency_p50_us)" -a "$(value "$A" status.last.latency_p50_us)" -le "$(value "$A" status.last.latency_p99_us)" \
  -a "$(value "$A" status.last.latency_p99_us)" -le "$(value "$A" status.last.latency_p999_us)" \
  -a "$(value "$A" status.last.latency_p999_us)" -le "$(value "$A" status.last.latency_max_us)"
OVERRUNS=$(value "$A" status.last.budget_overruns)
HEALTH=$(value "$A" status.last.health)
check "final status: health has no flag but (possibly) overrun; overruns <= steps" \
  test \( "$HEALTH" = 0 -o "$HEALTH" = 2 \) -a "$OVERRUNS" -le 400

# (2) equivalence with the offline run
check "daemon trajectory (lockstep) byte-identical to vislam-run's" cmp "$OUT/a.tum" "$OUT/offline.tum"
check "--step-samples: a line per frame, the trajectory's utimes in order, each step > 0 ns" cmp \
  <(awk '$2 > 0 { print $1 }' "$OUT/a.steps") \
  <(awk '!/^#/ { split($1, t, "."); printf "%d%06d\n", t[1], t[2] }' "$OUT/offline.tum")
MAPPED=$(value "$A" map.landmarks)
check "VISLAM_LANDMARKS: $MAPPED landmarks in $(value "$A" map.batches) batches, numbered in order, well formed, decoded" \
  test "$MAPPED" -gt 0 -a "$(value "$A" map.sequence_ok)/$(value "$A" map.well_formed)/$(value "$A" map.decode_errors)" = "1/1/0"
check "VISLAM_LANDMARKS: as many landmarks as the final status' landmarks_mapped" \
  eq "$MAPPED" "$(value "$A" status.last.landmarks_mapped)"
check "the daemon's map (window flushed at exit) byte-identical to vislam-run --map's" \
  cmp "$OUT/a.map.ply" "$OUT/offline.ply"

# (8) --stats-json
check "--stats-json: 400 steps (200 propagations, 200 updates), the histograms' counts the same, SIGTERM" \
  eq "$(value "$J" steps)/$(value "$J" step_latency.all.count)/$(value "$J" step_latency.propagation.count)/$(value "$J" step_latency.update.count)/$(value "$J" stopped_by)" \
  "400/400/200/200/SIGTERM"
check "--stats-json: 0 < median <= p99 <= p99.9 <= max of all steps" \
  test 0 -lt "$(value "$J" step_latency.all.median_us)" -a "$(value "$J" step_latency.all.median_us)" -le "$(value "$J" step_latency.all.p99_us)" \
  -a "$(value "$J" step_latency.all.p99_us)" -le "$(value "$J" step_latency.all.p999_us)" \
  -a "$(value "$J" step_latency.all.p999_us)" -le "$(value "$J" step_latency.all.max_us)"
check "--stats-json: budget and overruns as the final status has them, the sensor period" \
  eq "$(value "$J" budget_us)/$(value "$J" overruns)/$(value "$J" budget_source)" "$(value "$A" status.last.budget_us)/$OVERRUNS/sensor_period"
check "--stats-json: landmarks published = the recorded map's, poses out 400, 200 trajectory lines" \
  eq "$(value "$J" daemon.landmarks_out)/$(value "$J" session.poses_out)/$(value "$J" daemon.trajectory_lines)" "$MAPPED/400/200"
check "--stats-json: the core's counters equal vislam-run --stats-json's" eq "$(value "$J" core_counters_equal_offline)" 1
printf 'sample\t%s\t%s\n' "$OUT/a.stats.json" "$OUT/a.replay.json" >"$OUT/bench.rows"
PYTHONPATH="$SRC/tools" "$PYTHON" -m vislam_tools.bench_report daemon "$OUT/bench.rows" >"$OUT/bench.md"
check "tools/bench.sh's daemon table from --stats-json: 400 steps, the overruns, 200 of 200 poses back" \
  grep -Eq "^\| sample \| 400 \| $(value "$J" budget_us) \| $OVERRUNS \| [0-9]+ / [0-9]+ / [0-9]+ / [0-9]+ \|.*\| 200 of 200 \|" "$OUT/bench.md"

# (4) allocations after start-up
if [ -n "$ALLOC_SO" ]; then
  # The preloaded counter's own report (tests/support/vl_alloc_counter.c), armed by the daemon's
  # mlockall at the end of its start-up; the daemon knows nothing of it.
  ALLOC_PROC=$(value "$OUT/a.alloc" alloc.process_after_arm)
  ALLOC_MAIN=$(value "$OUT/a.alloc" alloc.armed_thread_after_arm)
  check "allocation counter armed at the end of the daemon's start-up, and reported" eq "$(value "$OUT/a.alloc" alloc.armed)" 1
  check "no heap allocation in the main (estimation) thread after start-up" eq "$ALLOC_MAIN" 0
  # The daemon reads its inputs on the socket itself (vl_lcm_rx), so liblcm starts no receive
  # thread (which would allocate the first time it sees each channel name): nothing anywhere.
  check "no heap allocation in the whole process after start-up (measured $ALLOC_PROC)" eq "$ALLOC_PROC" 0
else
  echo "skip: heap allocation checks (no allocation counter: a sanitizer build; the plain build runs them)"
fi

# ---- run B: SIGTERM in the middle of a real-time replay ----------------------------------------
echo "== run B: SIGTERM in the middle of a replay at the recorded rate"
start_recording b '(VISLAM_POSE|VISLAM_STATUS)' "$OUT/b.daemon.err" -- \
  "$BIN/vislamd" --lcm-url "$URL" --trajectory "$OUT/b.tum" --quiet
"$BIN/vislam-replay" "$LOG" --lcm-url "$URL" --lockstep --timeout-ms 1000 \
  --quiet 2>"$OUT/b.replay.err" &
REPLAY=$!
PIDS+=("$REPLAY")
# Mid-run: a status says 20 frames arrived (of 200, at 10 per second).
wait_recorded "$OUT/b.lcmlog" status.last.frames_in 20 30
record_stop b
check "daemon B exits 0 on SIGTERM mid-run" eq "$WAIT_RC" 0
kill -INT "$REPLAY" 2>/dev/null
wait_exit "$REPLAY" 10
"$INSPECT" "$OUT/b.lcmlog" >"$OUT/b.inspect"
B=$OUT/b.inspect
LINES_B=$(wc -l <"$OUT/b.tum")
echo "      stopped after $LINES_B of $FRAMES frames"
check "some but not all frames processed before SIGTERM" test "$LINES_B" -gt 0 -a "$LINES_B" -lt "$FRAMES"
check "trajectory B is exactly the first $LINES_B lines of the offline one" \
  cmp "$OUT/b.tum" <(head -n "$LINES_B" "$OUT/offline.tum")
check "one trajectory line per published FEATURES pose (none lost)" eq "$(value "$B" pose.features)" "$LINES_B"
LAST_B=$(tail -n 1 "$OUT/b.tum" | awk '{ split($1, t, "."); printf "%d%06d\n", t[1], t[2] }')
check "last trajectory line is the last published frame pose" eq "$(value "$B" pose.last_features_utime)" "$LAST_B"
check "final status published: its poses_out equals the poses on the wire" \
  eq "$(value "$B" status.last.poses_out)" "$(value "$B" pose.count)"
check "final status: every input received was a step (steps = imu_in + frames_in, 0 rejected)" \
  eq "$(value "$B" status.last.steps)/$(value "$B" status.last.inputs_rejected)" \
  "$(($(value "$B" status.last.imu_in) + $(value "$B" status.last.frames_in)))/0"

# ---- run C: calibration from the config file, none on the wire -------------------------------
echo "== run C: --config with [calibration], the log's VISLAM_CALIB not played"
cat >"$OUT/calib.ini" <<'INI'
[calibration]
override_log = true
fx = 707.0912
fy = 707.0912
cx = 601.8873
cy = 183.1104
baseline = 0.5371506
cam_T_imu = -1.08863514e-03 -9.99976347e-01 6.78718180e-03 1.14389871e+00
            -8.51207214e-03 -6.77767115e-03 -9.99940872e-01 -3.12718471e-01
            9.99963177e-01 -1.14634293e-03 -8.50449310e-03 7.26546045e-01
            0 0 0 1
INI
"$BIN/vislam-run" "$LOG" --config "$OUT/calib.ini" --trajectory "$OUT/c.offline.tum" --quiet
check "vislam-run with the config file's calibration succeeds" eq $? 0
"$BIN/vislamd" --lcm-url "$URL" --config "$OUT/calib.ini" --trajectory "$OUT/c.tum" --quiet 2>"$OUT/c.daemon.err" &
DAEMON=$!
PIDS+=("$DAEMON")
"$BIN/vislam-replay" "$LOG" --lcm-url "$URL" --channels VISLAM_IMU,VISLAM_FEATURES --lockstep --speed 8 \
  --wait-for VISLAM_STATUS --timeout-ms 5000 --quiet 2>"$OUT/c.replay.err"
check "replay C without a calibration message: every frame's pose came back" eq $? 0
kill -TERM "$DAEMON"
wait_exit "$DAEMON" 10
check "daemon C exits 0 on SIGTERM" eq "$WAIT_RC" 0
check "daemon C trajectory has every frame" eq "$(wc -l <"$OUT/c.tum")" "$FRAMES"
check "daemon C trajectory byte-identical to vislam-run's with the same config" cmp "$OUT/c.tum" "$OUT/c.offline.tum"

# ---- run D: the same log twice into one daemon -------------------------------------------------
echo "== run D: the log replayed twice into one daemon (a new timeline 20 s back)"
start_recording d '(VISLAM_POSE|VISLAM_STATUS|VISLAM_LANDMARKS)' "$OUT/d.daemon.err" -- \
  "$BIN/vislamd" --lcm-url "$URL" --trajectory "$OUT/d.tum" --quiet
"$BIN/vislam-replay" "$LOG" --lcm-url "$URL" --lockstep --speed 8 --timeout-ms 5000 \
  --quiet 2>"$OUT/d1.replay.err"
check "replay D1 exits 0" eq $? 0
# The second pass's first inputs are refused (20 s back: a time jump) until they form a timeline:
# their frames get no pose, so this replay's lockstep times out on them and exits non-zero.
"$BIN/vislam-replay" "$LOG" --lcm-url "$URL" --lockstep --speed 8 --timeout-ms 300 --quiet 2>"$OUT/d2.replay.err"
record_stop d
check "daemon D exits 0 on SIGTERM" eq "$WAIT_RC" 0
"$INSPECT" "$OUT/d.lcmlog" >"$OUT/d.inspect"
D=$OUT/d.inspect
check "one re-initialization, on a new timeline; the inputs before it refused as time jumps (4)" \
  eq "$(value "$D" status.last.timeline_changes)/$(value "$D" status.last.resets)/$(value "$D" status.last.divergence_resets)/$(value "$D" status.last.time_jumps)" "1/1/0/4"
check "a status said TIMELINE_CHANGE (32) and TIME_REFUSED (16)" \
  test $(($(value "$D" status.health_any) & 48)) -eq 48
check "tracking again: every frame from the third of the second pass has a trajectory line (200 + 198)" \
  eq "$(wc -l <"$OUT/d.tum")" 398
check "every published pose is finite" eq "$(value "$D" pose.non_finite)" 0
check "the map: the second pass's landmarks in world 1, worlds in order, as many as the final status' mapped" \
  eq "$(value "$D" map.world_last)/$(value "$D" map.worlds_ordered)/$(value "$D" map.sequence_ok)/$(value "$D" map.landmarks)" \
  "1/1/1/$(value "$D" status.last.landmarks_mapped)"
check "the final status is healthy again (0 or overrun)" \
  test \( "$(value "$D" status.last.health)" = 0 -o "$(value "$D" status.last.health)" = 2 \)

# ---- run E: replaying what lcm-logger recorded in run A ------------------------------------------
echo "== run E: vislam-replay of run A's recording (the replay's inputs and the daemon's outputs)"
json_block() { # json_block FILE KEY: the lines of the JSON object KEY in vislam-replay's summary
  awk -v k="\"$2\": {" 'index($0, k) { on = 1 } on { print } on && /}/ { exit }' "$1"
}
A_STATUSES=$(value "$A" status.count)
"$BIN/vislam-replay" "$OUT/a.lcmlog" --lcm-url "$URL" --speed 20 --linger-ms 300 \
  --summary-json "$OUT/e1.json" 2>"$OUT/e1.err"
check "replay of the recording exits 0" eq $? 0
check "it says at start what it replays" grep -q 'replaying the input channels VISLAM_IMU, VISLAM_FEATURES, VISLAM_CALIB' "$OUT/e1.err"
# The recording's calibrations are the first replay's, re-published once a second of log time.
check "by default: the inputs sent (200 IMU, 200 frames, the calibrations)" \
  eq "$(json_block "$OUT/e1.json" channels | grep -cE '"(VISLAM_IMU|VISLAM_FEATURES)": 200|"VISLAM_CALIB": [1-9]')" 3
check "by default: the recorded outputs skipped and counted (400 VISLAM_POSE, 400 POSE, $A_STATUSES VISLAM_STATUS)" \
  eq "$(json_block "$OUT/e1.json" channels_skipped | grep -cE "\"(VISLAM_POSE|POSE)\": 400|\"VISLAM_STATUS\": $A_STATUSES,?\$")" 3
check "by default: nothing on VISLAM_POSE" grep -q '"poses_received": 0,' "$OUT/e1.json"
"$BIN/vislam-replay" "$OUT/a.lcmlog" --lcm-url "$URL" --speed 20 --linger-ms 300 --all-channels \
  --summary-json "$OUT/e2.json" 2>"$OUT/e2.err"
check "--all-channels: the recorded outputs sent too (400 VISLAM_POSE, 400 POSE), none skipped" \
  eq "$(json_block "$OUT/e2.json" channels | grep -cE '"(VISLAM_POSE|POSE)": 400')/$(grep -c '"events_skipped": 0,' "$OUT/e2.json")" 2/1
check "--all-channels: the recorded poses are on the wire (the replay's own subscription got some)" \
  test "$(sed -n 's/.*"poses_received": \([0-9]*\),/\1/p' "$OUT/e2.json")" -gt 0

echo "== $((SECONDS - START)) s, $FAILS failure(s)"
[ "$FAILS" -eq 0 ]
