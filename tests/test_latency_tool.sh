#!/usr/bin/env bash
# vislam-latency on data/sample.lcmlog, run by CTest:
#
#   tests/test_latency_tool.sh in-process|e2e BIN_DIR LOG_INSPECT SOURCE_DIR
#
# in-process: two passes as fast as possible without vislamd; the JSON has every key, its
#   percentiles are ordered (min <= p50 <= p99 <= p999 <= max), steps = frames in the log x
#   passes (frames counted by vl_log_inspect), the work per step is positive with max >= p50,
#   every IMU step does the same work, a frame with the IMU steps before it at least its own,
#   and the jitter probe ran; no CPU latency request unless asked (cpu_dma_latency_us null).
#   No spinner unless asked (keep_awake false). Then one pass with --cpu-dma-latency 0
#   --keep-awake: it succeeds, the JSON reports 0, and it says the request was held exactly when
#   /dev/cpu_dma_latency is writable here (refused, a warning and not a failure, otherwise); the
#   JSON says keep_awake and the summary that the spinner ran on --cpu.
# e2e: the same plus vislamd over LCM, in a private network namespace (exit 77, CTest's skip,
#   when unshare --net is not permitted): every frame's pose came back, one sample per step; the
#   LCM overhead has one sample per frame, 0 <= min <= p50 <= p99 <= max, and each frame's equals
#   its end-to-end latency (the replay's --latency-samples, kept in --work-dir) less vislamd's step
#   for the same utime (its --step-samples), recomputed here, and is below that latency; its
#   stages (from the two programs' CLOCK_REALTIME stamps) cover every frame, add up to it, leave
#   little unaccounted for (|other| p50 < 5 us) and none is negative (beyond the 1 us of the
#   kernel's stamps); the overhead less its queued stage covers every frame, below the overhead.
#   Then one pass each through liblcm's receive thread (--lcm-receive-thread),
#   busy-polling (--busy-poll-us) and --cpu-dma-latency 0 --keep-awake: every pose back, stages
#   for every frame; vislamd's log says whether it held the request and that its spinner ran.
# No -e: every check runs and is reported; the exit status counts the failed ones.
set -uo pipefail

if [ $# -ne 4 ]; then
  echo "usage: $0 in-process|e2e BIN_DIR LOG_INSPECT SOURCE_DIR" >&2
  exit 2
fi
MODE=$1
BIN=$2
INSPECT=$3
SRC=$4
LOG="$SRC/data/sample.lcmlog"
URL='udpm://239.255.76.67:7667?ttl=0'
PASSES=2
PYTHON=${VISLAM_PYTHON:-python3}
FAILS=0
# shellcheck source=support/vl_record.sh
. "$SRC/tests/support/vl_record.sh"

if [ "$MODE" = e2e ]; then
  enter_private_netns "$0" "$@"
fi
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT

# The JSON's facts as "key value" lines, for value/eq/le below.
facts() {
  "$PYTHON" - "$1" "$2" "$PASSES" <<'PY'
import json, os, sys
d = json.load(open(sys.argv[1]))
keys = ["window", "steps", "step_us", "e2e_us", "lcm_overhead_us", "jitter_floor_us", "overruns", "work",
        "propagate_work", "frame_work"]
print("keys_ok", int(all(k in d for k in keys)))
def ordered(s):
    return int(s is not None and s["min"] <= s["p50"] <= s["p99"] <= s["p999"] <= s["max"])
print("step_ordered", ordered(d["step_us"]))
print("e2e_ordered", ordered(d["e2e_us"]))
print("steps", d["steps"])
print("window", d["window"])
print("overruns_int", int(isinstance(d["overruns"], int) and d["overruns"] >= 0))
print("work_ok", int(d["work"]["max"] >= d["work"]["p50"] > 0))
pw, fw, w = d["propagate_work"], d["frame_work"], d["work"]
print("propagate_work_flat", int(pw["max"] == pw["p50"] > 0))
print("frame_work_ok", int(fw["p50"] >= w["p50"] and fw["max"] >= w["max"]))
j = d["jitter_floor_us"]
print("jitter_ok", int(j is not None and j["samples"] > 0 and j["max"] >= 0))
print("e2e_returned", d["e2e_frames"]["returned"])
print("cpu_dma_latency_us", "null" if d["cpu_dma_latency_us"] is None else d["cpu_dma_latency_us"])
print("cpu_dma_latency_held", int(d["cpu_dma_latency_held"]))
print("keep_awake", int(d["keep_awake"]))
print("e2e_samples", len(d["samples"]["e2e_us"]))
lcm = d["lcm_overhead_us"]
print("lcm_n", 0 if lcm is None else lcm["n"])
print("lcm_samples", len(d["samples"]["lcm_overhead_us"]))
print("lcm_ordered", int(lcm is not None and 0 <= lcm["min"] <= lcm["p50"] <= lcm["p99"] <= lcm["max"]))
# Per frame, from the helpers' own files: e2e_K.txt (latency us, utime) and steps_K.txt (utime, ns).
work, lats, expect = sys.argv[2], [], []
for k in range(int(sys.argv[3])):
    e2e = os.path.join(work, f"e2e_{k}.txt")
    if not os.path.exists(e2e):
        continue
    steps = dict(tuple(map(int, l.split()[:2])) for l in open(os.path.join(work, f"steps_{k}.txt")))
    for line in open(e2e):
        lat, utime = map(int, line.split()[:2])
        lats.append(lat)
        expect.append(lat - steps[utime] / 1000.0)
got = d["samples"]["lcm_overhead_us"]
same = len(got) == len(expect) > 0
print("lcm_per_frame", int(same and all(abs(a - b) < 0.01 for a, b in zip(got, expect))))
print("lcm_below_e2e", int(same and all(a < b for a, b in zip(got, lats))))
st = d["lcm_stages_us"]
per = d["samples"]["lcm_stages_us"]
print("stages_n", 0 if st is None else min(s["n"] for s in st.values()))
sums = [sum(v[i] for v in per.values()) for i in range(len(per["other"]))]
print("stages_add_up", int(len(sums) == len(got) > 0 and all(abs(a - b) < 0.01 for a, b in zip(sums, got))))
print("stages_other_small", int(st is not None and abs(st["other"]["p50"]) < 5.0))
timed = ["send", "queued_wake", "queued_step", "queued_publish", "wake", "decode", "return", "replay_wake"]
print("stages_not_negative", int(st is not None and all(st[k]["min"] >= -1.0 for k in timed)))
tr = d["lcm_transport_us"]
print("transport_ok", int(tr is not None and tr["n"] == lcm["n"] and tr["p50"] <= lcm["p50"] and tr["max"] <= lcm["max"]))
PY
}

frames=$(value <("$INSPECT" "$LOG") channel.VISLAM_FEATURES)
expected=$((frames * PASSES))
args=("$LOG" --rate max --passes "$PASSES" --json "$OUT/l.json" --work-dir "$OUT/work" --quiet)
if [ "$MODE" = e2e ]; then
  args+=(--lcm-url "$URL")
else
  args+=(--no-e2e)
fi
echo "== vislam-latency ${args[*]}"
rc=0
"$BIN/vislam-latency" "${args[@]}" 2>"$OUT/stderr" || rc=$?
cat "$OUT/stderr"
check "exit status 0" eq "$rc" 0
facts "$OUT/l.json" "$OUT/work" >"$OUT/facts" || echo "FAIL: the JSON does not parse"
check "every key of the JSON" eq "$(value "$OUT/facts" keys_ok)" 1
check "steps = $frames frames x $PASSES passes" eq "$(value "$OUT/facts" steps)" "$expected"
check "window = the default 128" eq "$(value "$OUT/facts" window)" 128
check "step percentiles ordered" eq "$(value "$OUT/facts" step_ordered)" 1
check "work max >= p50 > 0" eq "$(value "$OUT/facts" work_ok)" 1
check "an IMU step's work does not depend on the state: max = p50 > 0" eq "$(value "$OUT/facts" propagate_work_flat)" 1
check "a frame's work with the IMU steps before it >= the frame step's" eq "$(value "$OUT/facts" frame_work_ok)" 1
check "overruns counted" eq "$(value "$OUT/facts" overruns_int)" 1
check "the jitter probe ran" eq "$(value "$OUT/facts" jitter_ok)" 1
if [ "$MODE" = e2e ]; then
  check "end to end: every pose came back" eq "$(value "$OUT/facts" e2e_returned)" "$expected"
  check "end to end: one sample per step" eq "$(value "$OUT/facts" e2e_samples)" "$expected"
  check "end-to-end percentiles ordered" eq "$(value "$OUT/facts" e2e_ordered)" 1
  check "LCM overhead: one sample per frame" eq "$(value "$OUT/facts" lcm_n)/$(value "$OUT/facts" lcm_samples)" \
    "$expected/$expected"
  check "LCM overhead: 0 <= min <= p50 <= p99 <= max" eq "$(value "$OUT/facts" lcm_ordered)" 1
  check "LCM overhead per frame = end to end - vislamd's step (its utime)" eq "$(value "$OUT/facts" lcm_per_frame)" 1
  check "LCM overhead below the end-to-end latency, every frame" eq "$(value "$OUT/facts" lcm_below_e2e)" 1
  check "LCM overhead stages for every frame" eq "$(value "$OUT/facts" stages_n)" "$expected"
  check "LCM overhead stages add up to each frame's overhead" eq "$(value "$OUT/facts" stages_add_up)" 1
  check "LCM overhead stages: what they leave out is small (|other| p50 < 5 us)" \
    eq "$(value "$OUT/facts" stages_other_small)" 1
  check "LCM overhead stages: none negative" eq "$(value "$OUT/facts" stages_not_negative)" 1
  check "LCM overhead less queued: every frame, below the overhead" eq "$(value "$OUT/facts" transport_ok)" 1
  for variant in --lcm-receive-thread "--busy-poll-us 2000" "--cpu-dma-latency 0 --keep-awake"; do
    # shellcheck disable=SC2086 # the variant is an option and its value
    "$BIN/vislam-latency" "$LOG" --rate max --passes 1 --no-probe --lcm-url "$URL" $variant --json "$OUT/v.json" \
      --work-dir "$OUT/work_v" --quiet 2>"$OUT/stderr_v" || cat "$OUT/stderr_v"
    PASSES=1 facts "$OUT/v.json" "$OUT/work_v" >"$OUT/facts_v" || echo "FAIL: the JSON does not parse"
    check "$variant: every pose came back" eq "$(value "$OUT/facts_v" e2e_returned)" "$frames"
    check "$variant: LCM overhead stages for every frame" eq "$(value "$OUT/facts_v" stages_n)" "$frames"
  done
  check "vislamd reports its --cpu-dma-latency request" eq \
    "$(grep -c 'CPU wake-up latency: at most 0 us\|cannot open /dev/cpu_dma_latency' "$OUT/work_v/vislamd_0.log")" 1
  check "--keep-awake: in the JSON" eq "$(value "$OUT/facts_v" keep_awake)" 1
  check "--keep-awake: vislamd's spinner ran on its CPU (exit summary)" \
    grep -qE 'keep awake \(--keep-awake\): CPU [0-9]+, a SCHED_IDLE thread spun [0-9]+ loops' "$OUT/work_v/vislamd_0.log"
else
  check "no end-to-end figures without vislamd" eq "$(value "$OUT/facts" e2e_samples)" 0
  check "no LCM overhead without vislamd" eq "$(value "$OUT/facts" lcm_samples)" 0
  check "no CPU latency request unless asked" eq "$(value "$OUT/facts" cpu_dma_latency_us)" null
  check "no spinner unless asked" eq "$(value "$OUT/facts" keep_awake)" 0
  rc=0
  "$BIN/vislam-latency" "$LOG" --rate max --passes 1 --no-probe --no-e2e --cpu-dma-latency 0 --keep-awake --json "$OUT/q.json" \
    --work-dir "$OUT/work_q" --quiet 2>"$OUT/stderr_q" || rc=$?
  cat "$OUT/stderr_q"
  check "--cpu-dma-latency 0: exit status 0" eq "$rc" 0
  PASSES=1 facts "$OUT/q.json" "$OUT/work_q" >"$OUT/facts_q" || echo "FAIL: the JSON does not parse"
  check "--cpu-dma-latency 0: reported" eq "$(value "$OUT/facts_q" cpu_dma_latency_us)" 0
  writable=0
  [ -w /dev/cpu_dma_latency ] && writable=1
  check "--cpu-dma-latency 0: held exactly when /dev/cpu_dma_latency is writable" \
    eq "$(value "$OUT/facts_q" cpu_dma_latency_held)" "$writable"
  check "--keep-awake: in the JSON" eq "$(value "$OUT/facts_q" keep_awake)" 1
  check "--keep-awake: the spinner ran on --cpu in-process" \
    grep -qE 'keep awake: CPU [0-9]+, a SCHED_IDLE thread spun [0-9]+ loops in-process' "$OUT/stderr_q"
fi
echo "$FAILS check(s) failed"
exit "$FAILS"
