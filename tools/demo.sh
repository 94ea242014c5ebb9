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
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
DATASET=""
SPEED=""
OUT_DIR="$REPO_ROOT/out/demo"
LCM_URL="${LCM_DEFAULT_URL:-}"
FORCE_NETNS=0

usage() { sed -n '2,12p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; }
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

# ---- set-up and build ---------------------------------------------------------------------------
# shellcheck source=tools/setup.sh
. "$REPO_ROOT/tools/setup.sh"
vl_setup_all
BUILD_DIR="${BUILD_DIR:-$REPO_ROOT/build}"
echo "== build ($BUILD_DIR)"
cmake -S "$REPO_ROOT" -B "$BUILD_DIR" -DCMAKE_BUILD_TYPE=Release -DUNITY_ROOT="$VL_UNITY_ROOT" >/dev/null
cmake --build "$BUILD_DIR" -j2 >/dev/null
export VISLAM_BUILD_DIR="$BUILD_DIR"
mkdir -p "$OUT_DIR"

# ---- the log and its truth ----------------------------------------------------------------------
GT=()
CALIB=()
if [ -z "$DATASET" ]; then
  LOG="$REPO_ROOT/data/sample.lcmlog"
  GT=(--gt "$REPO_ROOT/data/sample_truth.tum")
  SPEED="${SPEED:-1}"
  NAME="sample"
else
  [ -f "$DATASET" ] || { echo "demo.sh: no dataset at $DATASET" >&2; exit 2; }
  NAME="$(basename "$DATASET" .npz)"
  LOG="$OUT_DIR/$NAME.lcmlog"
  echo "== converting $DATASET"
  "$REPO_ROOT/tools/npz2lcm" "$DATASET" "$LOG"
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
echo "== replaying $NAME into vislamd at ${SPEED}x (lockstep)"
if [ "$needs_netns" -eq 1 ]; then
  echo "   LCM: private network namespace (udpm on its own loopback)"
  VL_DEMO_IN_NETNS=1 VL_DEMO_BUILD_DIR="$BUILD_DIR" VL_DEMO_LOG="$LOG" OUT_DIR="$OUT_DIR" \
    unshare --net bash "${BASH_SOURCE[0]}" --out "$OUT_DIR" --speed "$SPEED"
else
  url="${LCM_URL:-udpm://239.255.76.67:7667?ttl=0}"
  echo "   LCM: host, $url"
  run_lcm_part "$url"
fi

# ---- what a user wants to know ------------------------------------------------------------------
"$BUILD_DIR/bin/vislam-run" "$LOG" --mode imu_only --trajectory "$OUT_DIR/dead_reckoning.tum" --quiet
"$BUILD_DIR/bin/vislam-run" "$LOG" --trajectory "$OUT_DIR/offline.tum" --map "$OUT_DIR/map.ply" --quiet
echo
echo "== summary ($NAME)"
grep -E "^  in: |budget .*overrun|all steps  :|propagation:|update     :" "$OUT_DIR/vislamd.log" | sed 's/^ */   vislamd: /'
grep -E "poses received|end-to-end" "$OUT_DIR/replay.log" | sed 's/^ */   replay:  /'
if cmp -s "$OUT_DIR/trajectory.tum" "$OUT_DIR/offline.tum"; then
  echo "   the daemon's trajectory equals vislam-run's offline one, byte for byte"
else
  echo "   NOTE: the daemon's trajectory differs from vislam-run's offline one"
fi
if [ ${#GT[@]} -gt 0 ]; then
  "$REPO_ROOT/tools/evaluate" ate --estimate "$OUT_DIR/trajectory.tum" "${GT[@]}" "${CALIB[@]}" \
    | grep -E "^(ATE|RPE)" | sed 's/^/   slam:            /'
  "$REPO_ROOT/tools/evaluate" ate --estimate "$OUT_DIR/dead_reckoning.tum" "${GT[@]}" "${CALIB[@]}" \
    | grep -E "^ATE" | sed 's/^/   dead reckoning:  /'
fi
"$REPO_ROOT/tools/evaluate" plot --estimate "$OUT_DIR/trajectory.tum" \
  --dead-reckoning "$OUT_DIR/dead_reckoning.tum" --map "$OUT_DIR/map.ply" \
  "${GT[@]}" "${CALIB[@]}" --out "$OUT_DIR/trajectory.png" >/dev/null
echo "   figure: $OUT_DIR/trajectory.png"
echo "   outputs: $OUT_DIR (trajectory.tum, map.ply, vislamd.log, replay.log)"
