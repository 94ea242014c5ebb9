#!/usr/bin/env bash
# The main job on a fresh clone: set up, build, start vislamd, replay a log into it over LCM,
# and report what a user wants to know.
#
#   tools/demo.sh                                   the synthetic sample in data/ at sensor rate
#   tools/demo.sh --dataset ../shared/data/0027.npz a seed dataset (converted on the fly), 4x speed
#   tools/demo.sh --speed 2 --out /tmp/vislam-demo  options: replay speed-up, output folder
#
# LCM traffic runs in a private network namespace when the host has no multicast route (or
# when --netns is given), and on the host's LCM otherwise (--lcm-url to choose the URL).
# Prints: poses published, ATE against the truth (the sample's, or KITTI's for 0027), step
# latency percentiles, budget overruns, end-to-end latency; writes the trajectory figure (PNG).
# Shows one line per step (set-up, build, log, run, evaluate) and, on a terminal, the progress of
# the long ones; every step's own output goes to a file in the output folder.
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
DATASET=""
SPEED=""
OUT_DIR="$REPO_ROOT/out/demo"
LCM_URL="${LCM_DEFAULT_URL:-}"
FORCE_NETNS=0

usage() { sed -n '2,14p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; }
while [ $# -gt 0 ]; do
  case "$1" in
    --dataset) DATASET="$2"; shift 2 ;;
    --speed) SPEED="$2"; shift 2 ;;
    --out) OUT_DIR="$2"; shift 2 ;;
    --lcm-url) LCM_URL="$2"; shift 2 ;;
    --netns) FORCE_NETNS=1; shift ;;
    -h|--help) usage; exit 0 ;;
    *) echo "demo.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done

# ---- inside the private namespace: only the LCM part runs here ----------------------------------
if [ -n "${VL_DEMO_IN_NETNS:-}" ]; then
  ip link set lo up multicast on
  ip route add 224.0.0.0/4 dev lo
fi

run_lcm_part() {
  local url=$1
  local bin="$BUILD_DIR/bin"
  rm -f "$OUT_DIR/trajectory.tum" # vislamd appends to an existing trajectory; this is a new run
  "$bin/vislamd" --lcm-url "$url" --trajectory "$OUT_DIR/trajectory.tum" 2>"$OUT_DIR/vislamd.log" &
  local daemon=$!
  local replay_rc=0
  "$bin/vislam-replay" "$LOG" --lcm-url "$url" --lockstep --speed "$SPEED" --wait-for VISLAM_STATUS \
    2>"$OUT_DIR/replay.log" || replay_rc=$?
  kill -TERM "$daemon" 2>/dev/null || true
  local daemon_rc=0
  wait "$daemon" || daemon_rc=$?
  if [ "$replay_rc" -ne 0 ] || [ "$daemon_rc" -ne 0 ]; then
    echo "demo.sh: replay exited $replay_rc, vislamd exited $daemon_rc; see $OUT_DIR/replay.log and vislamd.log" >&2
    return 1
  fi
}

if [ -n "${VL_DEMO_IN_NETNS:-}" ]; then
  BUILD_DIR="$VL_DEMO_BUILD_DIR"; LOG="$VL_DEMO_LOG"
  run_lcm_part "udpm://239.255.76.67:7667?ttl=0"
  exit $?
fi

# ---- what the user sees: one line per step, progress on a terminal, the details in files ------
TTY=0
if [ -t 1 ]; then
  TTY=1
fi
COLUMNS_SHOWN=$(($( (tput cols 2>/dev/null || echo 80) | tail -n 1) - 8))
STEPS=5
step() { # step N TEXT
  echo "[$1/$STEPS] $2"
}
progress() { # progress TEXT: rewrites one line under the step's, on a terminal only
  if [ "$TTY" -eq 1 ]; then
    printf '\r\033[K      %.*s' "$COLUMNS_SHOWN" "$1"
  fi
}
progress_end() {
  if [ "$TTY" -eq 1 ]; then
    printf '\r\033[K'
  fi
}
show_lines() { # each line read becomes the progress line (a build's "[ 42%] Building ..." lines)
  local line
  while IFS= read -r line; do
    progress "$line"
  done
}
# logged LOG COMMAND...: COMMAND's output into LOG, its latest line as the progress line. COMMAND
# runs in this shell (a function keeps what it sets). On failure: the log's end, and exit.
logged() {
  local log=$1 rc=0
  shift
  "$@" > >(tee "$log" | show_lines) 2>&1 || rc=$?
  wait $! 2>/dev/null || true # the progress reader, done with the last line
  progress_end
  if [ "$rc" -ne 0 ]; then
    echo "demo.sh: failed (exit $rc); the end of $log:" >&2
    tail -n 20 "$log" | sed 's/^/   /' >&2
    exit "$rc"
  fi
}

# ---- set-up and build ---------------------------------------------------------------------------
mkdir -p "$OUT_DIR"
# shellcheck source=tools/setup.sh
. "$REPO_ROOT/tools/setup.sh"
step 1 "set-up: Debian packages, Unity, Python environment (log: $OUT_DIR/setup.log)"
logged "$OUT_DIR/setup.log" vl_setup_all
BUILD_DIR="${BUILD_DIR:-$REPO_ROOT/build}"
step 2 "build: $BUILD_DIR (log: $OUT_DIR/build.log)"
build() {
  cmake -S "$REPO_ROOT" -B "$BUILD_DIR" -DCMAKE_BUILD_TYPE=Release -DUNITY_ROOT="$VL_UNITY_ROOT" &&
    cmake --build "$BUILD_DIR" -j2
}
logged "$OUT_DIR/build.log" build
echo "      $("$BUILD_DIR/bin/vislamd" --version)"
export VISLAM_BUILD_DIR="$BUILD_DIR"

# ---- the log and its truth ----------------------------------------------------------------------
GT=()
CALIB=()
if [ -z "$DATASET" ]; then
  LOG="$REPO_ROOT/data/sample.lcmlog"
  GT=(--gt "$REPO_ROOT/data/sample_truth.tum")
  SPEED="${SPEED:-1}"
  NAME="sample"
  step 3 "log: data/sample.lcmlog, simulated by vislam-sim with its truth (data/README.md)"
else
  [ -f "$DATASET" ] || { echo "demo.sh: no dataset at $DATASET" >&2; exit 2; }
  NAME="$(basename "$DATASET" .npz)"
  LOG="$OUT_DIR/$NAME.lcmlog"
  step 3 "log: converting $DATASET (log: $OUT_DIR/npz2lcm.log)"
  logged "$OUT_DIR/npz2lcm.log" "$REPO_ROOT/tools/npz2lcm" "$DATASET" "$LOG"
  echo "      $(tail -n 1 "$OUT_DIR/npz2lcm.log")"
  SPEED="${SPEED:-4}"
  kitti="$(dirname "$DATASET")/gt/kitti_odometry_07.txt"
  if [ "$NAME" = "0027" ] && [ -f "$kitti" ]; then
    GT=(--gt "$kitti")
    CALIB=(--calib "$DATASET")
  fi
fi

# ---- run: vislamd fed by vislam-replay over LCM -------------------------------------------------
needs_netns=$FORCE_NETNS
if [ -z "$LCM_URL" ] && ! ip route get 239.255.76.67 >/dev/null 2>&1; then
  needs_netns=1
fi
step 4 "run: vislam-run offline, then vislamd fed by vislam-replay at ${SPEED}x in lockstep (logs: vislamd.log, replay.log)"
progress "vislam-run: dead reckoning and the offline reference"
"$BUILD_DIR/bin/vislam-run" "$LOG" --mode imu_only --trajectory "$OUT_DIR/dead_reckoning.tum" --quiet
"$BUILD_DIR/bin/vislam-run" "$LOG" --trajectory "$OUT_DIR/offline.tum" --map "$OUT_DIR/map.ply" --quiet
progress_end
FRAMES=$(wc -l <"$OUT_DIR/offline.tum")
rm -f "$OUT_DIR/trajectory.tum"
if [ "$needs_netns" -eq 1 ]; then
  echo "      LCM: private network namespace (udpm on its own loopback)"
  VL_DEMO_IN_NETNS=1 VL_DEMO_BUILD_DIR="$BUILD_DIR" VL_DEMO_LOG="$LOG" OUT_DIR="$OUT_DIR" \
    unshare --net bash "${BASH_SOURCE[0]}" --out "$OUT_DIR" --speed "$SPEED" &
else
  url="${LCM_URL:-udpm://239.255.76.67:7667?ttl=0}"
  echo "      LCM: host, $url"
  run_lcm_part "$url" &
fi
LCM_PART=$!
# Progress: the daemon's trajectory grows by one line per frame it estimated.
while kill -0 "$LCM_PART" 2>/dev/null; do
  done_frames=0
  if [ -f "$OUT_DIR/trajectory.tum" ]; then
    done_frames=$(wc -l <"$OUT_DIR/trajectory.tum")
  fi
  progress "vislamd: $done_frames of $FRAMES frames ($((100 * done_frames / (FRAMES > 0 ? FRAMES : 1)))%)"
  sleep 0.5 # the refresh period of the progress line
done
progress_end
lcm_rc=0
wait "$LCM_PART" || lcm_rc=$?
if [ "$lcm_rc" -ne 0 ]; then
  exit "$lcm_rc"
fi

# ---- what a user wants to know ------------------------------------------------------------------
step 5 "evaluate: against the offline run and the truth; the figure (log: $OUT_DIR/evaluate.log)"
: >"$OUT_DIR/evaluate.log"
SLAM_ATE=""
DR_ATE=""
if [ ${#GT[@]} -gt 0 ]; then
  progress "tools/evaluate ate"
  SLAM_ATE=$("$REPO_ROOT/tools/evaluate" ate --estimate "$OUT_DIR/trajectory.tum" "${GT[@]}" "${CALIB[@]}" \
    2>>"$OUT_DIR/evaluate.log" | tee -a "$OUT_DIR/evaluate.log" | grep -E "^(ATE|RPE)")
  DR_ATE=$("$REPO_ROOT/tools/evaluate" ate --estimate "$OUT_DIR/dead_reckoning.tum" "${GT[@]}" "${CALIB[@]}" \
    2>>"$OUT_DIR/evaluate.log" | tee -a "$OUT_DIR/evaluate.log" | grep -E "^ATE")
fi
progress "tools/evaluate plot: $OUT_DIR/trajectory.png"
"$REPO_ROOT/tools/evaluate" plot --estimate "$OUT_DIR/trajectory.tum" \
  --dead-reckoning "$OUT_DIR/dead_reckoning.tum" --map "$OUT_DIR/map.ply" \
  "${GT[@]}" "${CALIB[@]}" --out "$OUT_DIR/trajectory.png" >>"$OUT_DIR/evaluate.log" 2>&1
progress_end

echo
echo "== summary ($NAME)"
grep -E "^  in: |budget .*overrun|all steps  :|propagation:|update     :" "$OUT_DIR/vislamd.log" | sed 's/^ */   vislamd: /'
grep -E "poses received|end-to-end" "$OUT_DIR/replay.log" | sed 's/^ */   replay:  /'
if cmp -s "$OUT_DIR/trajectory.tum" "$OUT_DIR/offline.tum"; then
  echo "   the daemon's trajectory equals vislam-run's offline one, byte for byte"
else
  echo "   NOTE: the daemon's trajectory differs from vislam-run's offline one"
fi
if [ -n "$SLAM_ATE" ]; then
  sed 's/^/   slam:            /' <<<"$SLAM_ATE"
  sed 's/^/   dead reckoning:  /' <<<"$DR_ATE"
fi
echo "   figure: $OUT_DIR/trajectory.png"
echo "   outputs: $OUT_DIR (trajectory.tum, map.ply; logs: setup, build, vislamd, replay, evaluate)"
