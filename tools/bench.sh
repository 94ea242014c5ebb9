#!/usr/bin/env bash
# Benchmarks that print the figures (accuracy, robustness, window size, timing, daemon latency,
# trajectory figures, the accuracy test bed). Numbers only: no threshold ever fails the run.
#
#   tools/bench.sh                          every section (about 5-10 minutes)
#   tools/bench.sh --quick                  shorter variants (about 2-3 minutes)
#   tools/bench.sh --section timing ...     only these sections (repeatable, or comma-separated):
#                                           accuracy sweep window timing daemon figures conditions soak latency
#                                           reference
# Options: --data DIR (default ../shared/data), --build-dir DIR (default build-bench),
#          --no-build (use the build as it is), --cyclictest-seconds N (default 10, quick 5)
#
# Output: out/bench/ (git-ignored): report.md (the tables below, and every command run),
# logs/ (seed datasets converted with tools/npz2lcm), one folder per section, figures/.
# sweep: each noise value x0.1 to x10 on 0027 and clean-velocity 0027, adapted and fixed, the
# ablations, and the adapted cells on 0027 from 8 starts (tools/npz2lcm --start-step) with their means.
# conditions: every drive x feature density x velocity noise (tools/conditions), dead reckoning
# and the default, conditions/conditions.{json,png}, consistency_0027.png. It runs against any
# build, e.g. tools/bench.sh --section conditions --no-build --build-dir ../main/build
# reference: the NumPy reference filter beside vislam-run (tools/reference/compare) on the sample,
# 0027 and 0034; GTSAM's iSAM2 (tools/reference/isam2, only where gtsam is installed) against the
# truth on 0027 and two simulated drives, and against vislam on 0034.
# The seed datasets are read from --data; sections or rows that need them are skipped with a
# note when it is absent. Nothing derived from the datasets is written outside out/.
# Timing sections need root for cyclictest (SCHED_FIFO) and the daemon section for
# `unshare --net` (a private network namespace for LCM multicast); both skip with a note.
# No -e: a failed run is recorded as a warning and its cells as n/a, and the other sections go on.
set -uo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$REPO_ROOT" || exit 2
SELF="tools/bench.sh"
LCM_URL='udpm://239.255.76.67:7667?ttl=0'

# ---- inside the private network namespace: one vislamd + vislam-replay run -------------------
# bench.sh --daemon-inner BIN LOG PREFIX ALLOC_SO SPEED [VISLAMD OPTION...]
# (only via unshare, from section_daemon)
daemon_inner() {
  local bin=$1 log=$2 prefix=$3 alloc=$4 speed=$5 cmds daemon replay_rc daemon_rc
  shift 5
  local preload=() daemon_cmd replay_cmd
  cmds="${VL_BENCH_CMDS:-/dev/null}"
  ip link set lo up multicast on || return 3
  ip route add 224.0.0.0/4 dev lo || return 3
  [ -n "$alloc" ] && preload=(env VL_ALLOC_REPORT="$prefix.vislamd.alloc" LD_PRELOAD="$alloc")
  daemon_cmd=("${preload[@]}" "$bin/vislamd" --lcm-url "$LCM_URL" --trajectory "$prefix.tum"
    --stats-json "$prefix.vislamd.json" "$@")
  replay_cmd=("$bin/vislam-replay" "$log" --lcm-url "$LCM_URL" --lockstep --speed "$speed"
    --wait-for VISLAM_STATUS --timeout-ms 5000 --summary-json "$prefix.replay.json")
  {
    echo "# in a private network namespace (unshare --net):"
    echo "ip link set lo up multicast on; ip route add 224.0.0.0/4 dev lo"
    printf '%q ' "${daemon_cmd[@]}"; echo "2>$prefix.vislamd.log &"
    printf '%q ' "${replay_cmd[@]}"; echo "2>$prefix.replay.log"
    echo "kill -TERM \$vislamd_pid; wait"
  } >>"$cmds"
  rm -f "$prefix.tum" # vislamd appends to an existing trajectory; each run starts afresh
  "${daemon_cmd[@]}" 2>"$prefix.vislamd.log" &
  daemon=$!
  "${replay_cmd[@]}" 2>"$prefix.replay.log"
  replay_rc=$?
  kill -TERM "$daemon" 2>/dev/null
  wait "$daemon"
  daemon_rc=$?
  echo "replay exit $replay_rc, vislamd exit $daemon_rc"
  [ "$replay_rc" -eq 0 ] && [ "$daemon_rc" -eq 0 ]
}
# ---- inside the private network namespace: the soak (one vislamd, the logs looped) ------------
# bench.sh --soak-inner BIN ALLOC_SO OUT_DIR LOOPS LOG...  (only via unshare, from section_soak)
soak_inner() {
  local bin=$1 alloc=$2 out=$3 loops=$4 daemon loop log name rc
  shift 4
  ip link set lo up multicast on || return 3
  ip route add 224.0.0.0/4 dev lo || return 3
  local preload=()
  [ -n "$alloc" ] && preload=(env VL_ALLOC_REPORT="$out/vislamd.alloc" LD_PRELOAD="$alloc")
  rm -f "$out/soak.tum"
  "${preload[@]}" "$bin/vislamd" --lcm-url "$LCM_URL" --trajectory "$out/soak.tum" --stats-json "$out/vislamd.json" \
    2>"$out/vislamd.log" &
  daemon=$!
  printf 'loop\tlog\trss_kb\treplay_exit\tjson\n' >"$out/loops.tsv"
  for ((loop = 1; loop <= loops; loop++)); do
    for log in "$@"; do
      name=$(basename "$log" .lcmlog)
      rc=0
      "$bin/vislam-replay" "$log" --lcm-url "$LCM_URL" --lockstep --max --wait-for VISLAM_STATUS \
        --timeout-ms 2000 --max-timeouts 0 --quiet --summary-json "$out/l${loop}_$name.json" || rc=$?
      printf '%s\t%s\t%s\t%s\t%s\n' "$loop" "$name" "$(awk '/^VmRSS/ {print $2}' "/proc/$daemon/status")" "$rc" \
        "$out/l${loop}_$name.json" >>"$out/loops.tsv"
    done
  done
  kill -TERM "$daemon" 2>/dev/null
  wait "$daemon"
}
if [ "${1:-}" = "--soak-inner" ]; then
  shift
  soak_inner "$@"
  exit
fi
if [ "${1:-}" = "--daemon-inner" ]; then
  shift
  daemon_inner "$@"
  exit
fi

# ---- options ------------------------------------------------------------------------------------
ALL_SECTIONS=(accuracy sweep window timing daemon figures conditions soak latency reference)
QUICK=0
SECTIONS=()
DATA="../shared/data"
BUILD="build-bench"
DO_BUILD=1
CYCLIC_S=""
usage() { sed -n '2,20p' "$0" | sed 's/^# \{0,1\}//'; }
while [ $# -gt 0 ]; do
  case "$1" in
    --quick) QUICK=1; shift ;;
    --section) [ $# -ge 2 ] || { echo "$SELF: --section needs a name" >&2; exit 2; }
      IFS=',' read -r -a s <<<"$2"; SECTIONS+=("${s[@]}"); shift 2 ;;
    --data) DATA="$2"; shift 2 ;;
    --build-dir) BUILD="$2"; shift 2 ;;
    --no-build) DO_BUILD=0; shift ;;
    --cyclictest-seconds) CYCLIC_S="$2"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    *) echo "$SELF: unknown option $1 (see --help)" >&2; exit 2 ;;
  esac
done
[ ${#SECTIONS[@]} -eq 0 ] && SECTIONS=("${ALL_SECTIONS[@]}")
for s in "${SECTIONS[@]}"; do
  case " ${ALL_SECTIONS[*]} " in *" $s "*) ;; *) echo "$SELF: unknown section '$s' (${ALL_SECTIONS[*]})" >&2; exit 2 ;; esac
done
[ -z "$CYCLIC_S" ] && { [ "$QUICK" -eq 1 ] && CYCLIC_S=5 || CYCLIC_S=10; }

OUT="out/bench"
BIN="$BUILD/bin"
PY=".venv/bin/python"
REPORT="$OUT/report.md"
mkdir -p "$OUT/logs" "$OUT/sections" "$OUT/commands"
HAVE_DATA=0
[ -f "$DATA/0022.npz" ] && [ -f "$DATA/0027.npz" ] && [ -f "$DATA/0034.npz" ] && HAVE_DATA=1
GT07="$DATA/gt/kitti_odometry_07.txt"
WARNINGS=0

# ---- helpers ------------------------------------------------------------------------------------
SECTION=""
SEC_MD=""
SEC_CMDS=""
say() { printf '%s\n' "$*" | tee -a "$SEC_MD"; }            # to the terminal and the report
note() { printf '%s\n' "$*"; }                               # terminal only
warn() { printf 'WARNING: %s\n' "$*" | tee -a "$SEC_MD" >&2; WARNINGS=$((WARNINGS + 1)); }
# rec CMD...: append the command line to this section's command list
rec() { printf '%q ' "$@" | sed 's/ $//' >>"$SEC_CMDS"; echo >>"$SEC_CMDS"; }
# run LOGFILE CMD...: record, run with stdout and stderr appended to LOGFILE; warn on failure
run() {
  local logf=$1
  shift
  rec "$@"
  "$@" >>"$logf" 2>&1
  local rc=$?
  [ $rc -ne 0 ] && warn "exit $rc: $* (see $logf)"
  return $rc
}
table() { "$PY" -m vislam_tools.bench_report "$@" | tee -a "$SEC_MD"; }
begin_section() {
  SECTION=$1
  SEC_MD="$OUT/sections/$1.md"
  SEC_CMDS="$OUT/commands/$1.txt"
  : >"$SEC_MD"
  : >"$SEC_CMDS"
  SEC_START=$SECONDS
  echo
  say "## $2"
  say ""
}
end_section() {
  local t=$((SECONDS - SEC_START))
  SECTION_TIMES+=("$SECTION ${t}s")
  if [ -s "$SEC_CMDS" ]; then
    {
      echo
      echo "Commands (from the repository root):"
      echo
      echo '```'
      cat "$SEC_CMDS"
      echo '```'
    } >>"$SEC_MD"
    note "(commands: $SEC_CMDS)"
  fi
  say ""
  say "Section time: ${t} s"
}
need_data() {
  if [ "$HAVE_DATA" -eq 0 ]; then
    say "SKIPPED ($1): the seed datasets are not in $DATA (0022.npz, 0027.npz, 0034.npz);"
    say "pass --data DIR or put them at ../shared/data relative to the repository."
    return 1
  fi
}
# logfor NAME: the converted LCM log of a seed dataset (converted once, again when the npz is newer)
logfor() {
  local npz="$DATA/$1.npz" log="$OUT/logs/$1.lcmlog"
  if [ ! -s "$log" ] || [ "$npz" -nt "$log" ]; then
    run "$OUT/logs/npz2lcm.log" tools/npz2lcm "$npz" "$log" >/dev/null || return 1
  else
    rec tools/npz2lcm "$npz" "$log"
  fi
  echo "$log"
}
# ate_run DIR TAG LOG GT CALIB|"" ROWS LABEL DATA SETTINGS -- vislam-run options...
# runs vislam-run, evaluates against GT, appends a row for `bench_report ate`
ate_run() {
  local dir=$1 tag=$2 log=$3 gt=$4 calib=$5 rows=$6 label=$7 data=$8 settings=$9
  shift 10
  local calib_args=()
  [ -n "$calib" ] && calib_args=(--calib "$calib")
  rm -f "$dir/$tag.ate.json" "$dir/$tag.stats.json"
  run "$dir/runs.log" "$BIN/vislam-run" "$log" --trajectory "$dir/$tag.tum" --stats-json "$dir/$tag.stats.json" \
    --quiet "$@" &&
    run "$dir/runs.log" tools/evaluate ate --estimate "$dir/$tag.tum" --gt "$gt" "${calib_args[@]}" \
      --json "$dir/$tag.ate.json"
  printf '%s\t%s\t%s\t%s\t%s\n' "$label" "$data" "$settings" "$dir/$tag.ate.json" "$dir/$tag.stats.json" >>"$rows"
}

# ---- set-up and build -------------------------------------------------------------------------
T0=$SECONDS
SECTION_TIMES=()
if [ "$DO_BUILD" -eq 1 ]; then
  # shellcheck source=tools/setup.sh
  . tools/setup.sh
  set +e
  vl_setup_all >/dev/null || { echo "$SELF: set-up failed (tools/setup.sh)" >&2; exit 1; }
  echo "== build ($BUILD, Release)"
  if ! { cmake -S . -B "$BUILD" -DCMAKE_BUILD_TYPE=Release -DUNITY_ROOT="$VL_UNITY_ROOT" >"$OUT/build.log" 2>&1 &&
    cmake --build "$BUILD" -j2 >>"$OUT/build.log" 2>&1; }; then
    echo "$SELF: build failed, see $OUT/build.log" >&2
    exit 1
  fi
fi
for b in vislam-run vislamd vislam-replay; do
  [ -x "$BIN/$b" ] || { echo "$SELF: $BIN/$b missing (build first, or drop --no-build)" >&2; exit 1; }
done
[ -x "$PY" ] || { echo "$SELF: no venv at .venv (run tools/setup.sh)" >&2; exit 1; }
VISLAM_BUILD_DIR="$(cd "$BUILD" && pwd)"
export VISLAM_BUILD_DIR
export PYTHONPATH="$REPO_ROOT/tools${PYTHONPATH:+:$PYTHONPATH}"
native="$(sed -n 's/^VL_NATIVE:BOOL=//p' "$BUILD/CMakeCache.txt" 2>/dev/null)"
max_lm="$(sed -n 's/^VL_MAX_LANDMARKS:STRING=//p' "$BUILD/CMakeCache.txt" 2>/dev/null)"

# ---- 1. accuracy ---------------------------------------------------------------------------------
section_accuracy() {
  begin_section accuracy "1. Accuracy (ATE after a rigid SE(3) alignment, RPE)"
  local d="$OUT/accuracy"
  mkdir -p "$d"
  : >"$d/runs.log"
  local rows="$d/rows.tsv"
  : >"$rows"
  local variants=("dr|dead reckoning|--mode imu_only|--mode imu_only"
    "mapping|mapping|--mode mapping|--mode mapping"
    "seed|seed preset|--preset seed|--preset seed"
    "slam|default SLAM|(defaults)|")
  local v tag label settings opts log
  if need_data "KITTI 0027 rows"; then
    if [ -f "$GT07" ] && log=$(logfor 0027); then
      for v in "${variants[@]}"; do
        IFS='|' read -r tag label settings opts <<<"$v"
        # shellcheck disable=SC2086 # opts is a list of words
        ate_run "$d" "0027_$tag" "$log" "$GT07" "$DATA/0027.npz" "$rows" "$label" 0027 "$settings" -- $opts
      done
    else
      say "SKIPPED (0027): no ground truth at $GT07"
    fi
  fi
  for v in "${variants[@]}"; do
    IFS='|' read -r tag label settings opts <<<"$v"
    # shellcheck disable=SC2086
    ate_run "$d" "sample_$tag" data/sample.lcmlog data/sample_truth.tum "" "$rows" "$label" sample "$settings" -- $opts
  done
  say "0027 against KITTI odometry 07 (left camera poses mapped to the IMU with the npz's cam_T_imu);"
  say "sample = data/sample.lcmlog (simulated) against data/sample_truth.tum. RPE: RMSE of the relative"
  say "translation / rotation error over 1 and 10 steps. Counters from vislam-run --stats-json."
  say ""
  table ate "$rows"
  end_section
}

# ---- 2. sweep ------------------------------------------------------------------------------------
ini_value() { # ini_value SECTION KEY: the default configuration's value
  "$BIN/vislam-run" --print-config | awk -v s="[$1]" -v k="$2" '
    /^\[/ { cur = $1 } cur == s && $1 == k && $2 == "=" { print $3; exit }'
}
section_sweep() {
  begin_section sweep "2. Noise robustness and ablations (0027 and clean-velocity 0027, ATE)"
  need_data "the sweep runs on 0027" || { end_section; return; }
  [ -f "$GT07" ] || { say "SKIPPED: no ground truth at $GT07"; end_section; return; }
  local d="$OUT/sweep" log clean
  mkdir -p "$d/logs"
  : >"$d/runs.log"
  log=$(logfor 0027) || { end_section; return; }
  clean="$d/logs/0027_clean.lcmlog"
  cond_log "$d" 0027_clean "$DATA/0027.npz" --velocities clean --gt "$GT07" || clean=""
  local lv av px f
  lv=$(ini_value noise linear_velocity)
  av=$(ini_value noise angular_velocity)
  px=$(ini_value noise pixel)
  mul() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.6g", a * b }'; }
  # name|section.key=value;section.key=value (noise values scaled from the defaults)
  local sweeps=("default|")
  for f in 0.1 0.3 3 10; do
    sweeps+=("lv_x$f|noise.linear_velocity=$(mul "$lv" "$f")"
      "av_x$f|noise.angular_velocity=$(mul "$av" "$f")"
      "px_x$f|noise.pixel=$(mul "$px" "$f")")
  done
  local fixed=() e kvs
  for e in "${sweeps[@]}"; do
    kvs=${e#*|}
    fixed+=("fixed_${e%%|*}|estimator.adaptive_noise=false${kvs:+;$kvs}")
  done
  local ablations=("no_adaptation|estimator.adaptive_noise=false"
    "no_offsets|estimator.estimate_input_offsets=false"
    "no_ransac|outliers.ransac_hypotheses=0"
    "no_restarts|outliers.max_broken_fraction=1.0"
    "plain_ekf|outliers.gate_chi2=0"
    "track_len_1|landmarks.min_track_length=1"
    "all_obs|estimator.max_update_observations=0;estimator.max_update_work=0")
  run_list() { # run_list ROWS LOG DATA-LABEL ENTRY...
    local rows=$1 runlog=$2 label=$3 name kvs kv sec key settings
    shift 3
    : >"$rows"
    for e in "$@"; do
      IFS='|' read -r name kvs <<<"$e"
      if [ -z "$kvs" ]; then
        ate_run "$d" "${label}_$name" "$runlog" "$GT07" "$DATA/0027.npz" "$rows" "$name" "$label" "(defaults)" --
        continue
      fi
      echo "; tools/bench.sh sweep: $name (on top of the defaults)" >"$d/$name.ini"
      settings=""
      IFS=';' read -r -a kvarr <<<"$kvs"
      for kv in "${kvarr[@]}"; do
        sec=${kv%%.*}
        key=${kv#*.}
        printf '[%s]\n%s = %s\n' "$sec" "${key%%=*}" "${key#*=}" >>"$d/$name.ini"
        settings+="${settings:+, }[$sec] ${key%%=*} = ${key#*=}"
      done
      ate_run "$d" "${label}_$name" "$runlog" "$GT07" "$DATA/0027.npz" "$rows" "$name" "$label" "$settings" \
        -- --config "$d/$name.ini"
    done
  }
  say "Each noise standard deviation of the filter x0.1, x0.3, x3 and x10, one at a time (defaults:"
  say "linear_velocity $(mul "$lv" 1) m/s, angular_velocity $(mul "$av" 1) rad/s, pixel $(mul "$px" 1) px), with the"
  say "noise adapted online (the default) and fixed (adaptive_noise = false), on 0027 as given and on"
  say "0027 with clean velocities (derived from the ground truth, tools/conditions; dead reckoning is exact"
  say "there). INI files: $d/*.ini, each on top of the defaults (vislam-run --config)."
  local data_label data_log
  for data_label in 0027 0027_clean; do
    data_log=$log
    [ "$data_label" = 0027_clean ] && data_log=$clean
    [ -n "$data_log" ] || { say "SKIPPED: $data_label (no log)"; continue; }
    say ""
    say "$data_label, noise adapted online:"
    say ""
    run_list "$d/noise_$data_label.tsv" "$data_log" "$data_label" "${sweeps[@]}"
    table ate "$d/noise_$data_label.tsv"
    say ""
    say "$data_label, noise fixed at the configured values:"
    say ""
    run_list "$d/fixed_$data_label.tsv" "$data_log" "$data_label" "${fixed[@]}"
    table ate "$d/fixed_$data_label.tsv"
  done
  say ""
  say "Ablations on 0027 (one setting changed from the defaults):"
  say ""
  run_list "$d/ablations.tsv" "$log" 0027 "${ablations[@]}"
  { head -n 1 "$d/noise_0027.tsv"; cat "$d/ablations.tsv"; } >"$d/ablations_all.tsv" # the default row first
  table ate "$d/ablations_all.tsv"
  # One run of a drive moves by tenths of a metre with any change of which observations are used;
  # the mean over later starts is the steadier measure of a setting.
  local starts=(0 75 150 225 300 375 450 525) k name kvs cfg
  [ "$QUICK" -eq 1 ] && starts=(0 300)
  say ""
  say "0027 from ${#starts[@]} starts (the drive from steps ${starts[*]}: tools/npz2lcm --start-step K), the"
  say "noise adapted: each cell of the adapted table above, its ATE from each start and their mean."
  say ""
  : >"$d/starts.tsv"
  for k in "${starts[@]}"; do
    run "$d/runs.log" tools/npz2lcm "$DATA/0027.npz" "$d/logs/0027_s$k.lcmlog" --start-step "$k" || continue
    for e in "${sweeps[@]}"; do
      IFS='|' read -r name kvs <<<"$e"
      cfg=()
      [ -n "$kvs" ] && cfg=(--config "$d/$name.ini")
      rm -f "$d/s${k}_$name.ate.json"
      run "$d/runs.log" "$BIN/vislam-run" "$d/logs/0027_s$k.lcmlog" --trajectory "$d/s${k}_$name.tum" --quiet \
        "${cfg[@]}" &&
        run "$d/runs.log" tools/evaluate ate --estimate "$d/s${k}_$name.tum" --gt "$GT07" --calib "$DATA/0027.npz" \
          --json "$d/s${k}_$name.ate.json"
      kvs=$(sed -E 's/^([^.]*)\.([^=]*)=(.*)$/[\1] \2 = \3/' <<<"${kvs:-(defaults)}")
      printf '%s\t%s\t%s\t%s\n' "$name" "$kvs" "$k" "$d/s${k}_$name.ate.json" >>"$d/starts.tsv"
    done
  done
  table starts "$d/starts.tsv" --json "$d/starts.json"
  end_section
}

# ---- 3. window ------------------------------------------------------------------------------------
section_window() {
  begin_section window "3. Window size ([landmarks] max_landmarks): accuracy on 0027, update time on 0034"
  need_data "0027 and 0034" || { end_section; return; }
  local d="$OUT/window" l27 l34 n rows
  mkdir -p "$d"
  : >"$d/runs.log"
  rows="$d/rows.tsv"
  : >"$rows"
  if ! l27=$(logfor 0027) || ! l34=$(logfor 0034); then
    end_section
    return
  fi
  for n in 16 32 64 128; do
    if [ -n "$max_lm" ] && [ "$n" -gt "$max_lm" ]; then
      say "max_landmarks $n: above this build's capacity VL_MAX_LANDMARKS=$max_lm, skipped"
      continue
    fi
    rm -f "$d/0027_w$n.ate.json" "$d/0027_w$n.stats.json" "$d/0034_w$n.stats.json"
    run "$d/runs.log" "$BIN/vislam-run" "$l27" --max-landmarks "$n" --trajectory "$d/0027_w$n.tum" \
      --stats-json "$d/0027_w$n.stats.json" --quiet &&
      run "$d/runs.log" tools/evaluate ate --estimate "$d/0027_w$n.tum" --gt "$GT07" --calib "$DATA/0027.npz" \
        --json "$d/0027_w$n.ate.json"
    run "$d/runs.log" "$BIN/vislam-run" "$l34" --max-landmarks "$n" --trajectory "$d/0034_w$n.tum" \
      --stats-json "$d/0034_w$n.stats.json" --timing --quiet
    printf '%s\t%s\t%s\t%s\n' "$n" "$d/0027_w$n.ate.json" "$d/0027_w$n.stats.json" "$d/0034_w$n.stats.json" >>"$rows"
  done
  say "Wall time per call from vislam-run --timing (single run each, as fast as possible, build $BUILD,"
  say "VL_NATIVE=${native:-?}). Counters from --stats-json: landmarks deferred (new landmarks refused"
  say "for lack of room), landmarks evicted (pushed out of the window early to make room), observations"
  say "deferred (left out of a frame's update by [estimator] max_update_observations or max_update_work, where the build has them)."
  say ""
  table window "$rows"
  end_section
}

# ---- 4. timing ------------------------------------------------------------------------------------
section_timing() {
  begin_section timing "4. Timing of the core (default window)"
  local d="$OUT/timing" log name i rows
  mkdir -p "$d"
  : >"$d/runs.log"
  rows="$d/rows.tsv"
  : >"$rows"
  if [ "$HAVE_DATA" -eq 1 ] && log=$(logfor 0034); then
    name=0034
  else
    say "(seed datasets absent: timing on the sample log instead of 0034)"
    log=data/sample.lcmlog
    name=sample
  fi
  say "Host: $(nproc) CPUs, $(sed -n 's/^model name\s*: //p' /proc/cpuinfo | head -n 1); load average before: $(cut -d' ' -f1-3 /proc/loadavg)."
  say ""
  say "### Wall time per call on $name (vislam-run --timing, 3 runs, build $BUILD, VL_NATIVE=${native:-?})"
  say ""
  for i in 1 2 3; do
    rm -f "$d/${name}_run$i.stats.json"
    run "$d/runs.log" "$BIN/vislam-run" "$log" --trajectory "$d/$name.tum" --stats-json "$d/${name}_run$i.stats.json" \
      --timing --quiet
    printf 'run %s\t%s\n' "$i" "$d/${name}_run$i.stats.json" >>"$rows"
  done
  table timing "$rows" --json "$d/worst.json"
  local worst
  worst=$("$PY" -c 'import json,sys; w=json.load(open(sys.argv[1]))["worst_us"]; print("%.0f" % w if w else "n/a")' "$d/worst.json" 2>/dev/null || echo n/a)

  # scheduling-latency floor of this machine, measured right after the runs above
  say ""
  say "### Scheduling latency floor (cyclictest, right after the runs above)"
  say ""
  local cyc=""
  if [ "$(id -u)" -ne 0 ]; then
    say "SKIPPED: cyclictest needs root for SCHED_FIFO priority 80."
  else
    if ! command -v cyclictest >/dev/null 2>&1; then
      note "installing rt-tests (cyclictest)"
      DEBIAN_FRONTEND=noninteractive apt-get install -y rt-tests >"$d/apt.log" 2>&1 ||
        { apt-get update >>"$d/apt.log" 2>&1 && DEBIAN_FRONTEND=noninteractive apt-get install -y rt-tests >>"$d/apt.log" 2>&1; }
    fi
    if command -v cyclictest >/dev/null 2>&1; then
      # rt-tests 2.x dropped -n (clock_nanosleep is the default and only mode)
      : >"$d/cyclictest.log"
      run "$d/cyclictest.log" cyclictest -m -q -D "$CYCLIC_S" -t 2 -p 80 -i 1000
      cyc=$(awk '{ for (i = 1; i < NF; i++) if ($i == "Max:" && $(i + 1) > m) m = $(i + 1) } END { if (m != "") print m }' "$d/cyclictest.log")
      say '```'
      grep '^T:' "$d/cyclictest.log" | tee -a "$SEC_MD"
      say '```'
    else
      say "SKIPPED: cyclictest unavailable (apt-get install rt-tests failed, see $d/apt.log)."
    fi
  fi
  say ""
  say "Worst single core call (wall): ${worst} us; cyclictest max latency (${CYCLIC_S} s, 2 threads, SCHED_FIFO 80,"
  say "1 ms interval, mlockall): ${cyc:-n/a} us. The core runs at normal priority in vislam-run, so its"
  say "worst case includes preemption; cyclictest shows what the kernel alone costs on this host."

  # instruction counts
  say ""
  say "### Instruction counts (callgrind)"
  say ""
  local vb="$OUT/build-valgrind" cglog="$log" cgname=$name
  if ! command -v valgrind >/dev/null 2>&1; then
    say "SKIPPED: valgrind not installed."
  else
    if [ "$QUICK" -eq 1 ]; then
      cglog=data/sample.lcmlog
      cgname=sample
    fi
    note "building the portable variant for valgrind ($vb)"
    : >"$d/build-valgrind.log"
    local unity="${VL_UNITY_ROOT:-$REPO_ROOT/.deps/unity}"
    unity="${unity#"$REPO_ROOT"/}"
    # valgrind 3.19 cannot decode AVX-512 (and some AVX) encodings that -march=native emits here
    if run "$d/build-valgrind.log" cmake -S . -B "$vb" -DCMAKE_BUILD_TYPE=Release -DVL_NATIVE=OFF \
      -DUNITY_ROOT="$unity" &&
      run "$d/build-valgrind.log" cmake --build "$vb" -j2 --target vislam-run; then
      rm -rf "$d/callgrind"
      mkdir -p "$d/callgrind"
      : >"$d/callgrind.log"
      # one dump at the end of every vl_update: each holds one frame's propagation and update
      run "$d/callgrind.log" valgrind --tool=callgrind --dump-instr=no --dump-after=vl_update \
        --callgrind-out-file="$d/callgrind/callgrind.out" \
        "$vb/bin/vislam-run" "$cglog" --trajectory "$d/callgrind.tum" --quiet
      say "On $cgname, portable build (VL_NATIVE=OFF: x86-64 baseline, SSE2; valgrind cannot run the"
      say "native AVX-512 build), inclusive Ir of the calls to the core's two entry points (log reading and output excluded):"
      say ""
      table callgrind "$d/callgrind" --json "$d/callgrind.json"
      rm -rf "$d/callgrind" # about 50 MB of per-frame dumps; the totals are in callgrind.json
    else
      warn "portable build for valgrind failed (see $d/build-valgrind.log)"
    fi
  fi

  # state size
  say ""
  say "### State size"
  say ""
  cat >"$d/sizeof.c" <<'EOF'
#include <stdio.h>
#include "vislam/vislam.h"
int main(void)
{
    printf("%zu %d\n", sizeof(vl_estimator_t), VL_MAX_LANDMARKS);
    return 0;
}
EOF
  local def=()
  [ -n "$max_lm" ] && def=(-DVL_MAX_LANDMARKS="$max_lm")
  if run "$d/runs.log" cc -std=c99 -Icore/include "${def[@]}" "$d/sizeof.c" -o "$d/sizeof"; then
    local sz cap
    read -r sz cap < <("$d/sizeof")
    say "sizeof(vl_estimator_t) = $sz bytes ($(awk -v s="$sz" 'BEGIN { printf "%.2f MiB", s / 1048576 }')) at VL_MAX_LANDMARKS = $cap."
  fi
  end_section
}

# ---- 5. daemon ------------------------------------------------------------------------------------
section_daemon() {
  begin_section daemon "5. vislamd end to end (vislam-replay --lockstep at 1x over LCM)"
  local d="$OUT/daemon" rows alloc
  mkdir -p "$d"
  rows="$d/rows.tsv"
  : >"$rows"
  if ! unshare --net true 2>/dev/null || ! command -v ip >/dev/null 2>&1; then
    say "SKIPPED: needs a private network namespace (unshare --net: root or user namespaces) and ip (iproute2)."
    end_section
    return
  fi
  alloc=$(find "$BUILD" -name 'libvl_alloc_counter.so' -print -quit 2>/dev/null)
  [ -z "$alloc" ] && say "(no libvl_alloc_counter.so under $BUILD: allocations not counted)"
  local runs=("sample|data/sample.lcmlog")
  if [ "$QUICK" -eq 1 ]; then
    say "(--quick: sample log only; the full run also replays 0034 at 1x, about 2 minutes)"
  elif [ "$HAVE_DATA" -eq 1 ]; then
    local l34
    l34=$(logfor 0034) && runs+=("0034|$l34")
    # The same with the daemon as a robot would run it: SCHED_FIFO, pinned to the second core.
    if [ "$(id -u)" -eq 0 ] && [ -n "$l34" ]; then
      runs+=("0034 rt|$l34|--rt-priority 80 --cpu 1")
    fi
  else
    say "SKIPPED (0034): the seed datasets are not in $DATA."
  fi
  local r name log extra file
  for r in "${runs[@]}"; do
    IFS='|' read -r name log extra <<<"$r"
    file=${name// /_}
    note "replaying $name at 1x into vislamd ($(wc -c <"$log") bytes)"
    rm -f "$d/$file.replay.json" "$d/$file.vislamd.log" "$d/$file.vislamd.json"
    echo "# $name" >>"$SEC_CMDS"
    # shellcheck disable=SC2086 # $extra holds separate vislamd options
    if ! VL_BENCH_CMDS="$SEC_CMDS" unshare --net bash "$SELF" --daemon-inner "$BIN" "$log" "$d/$file" "$alloc" 1 $extra \
      >"$d/$file.inner.log" 2>&1; then
      warn "daemon run on $name failed: $(tail -n 1 "$d/$file.inner.log") (see $d/$file.*.log)"
    fi
    printf '%s\t%s\t%s\n' "$name" "$d/$file.vislamd.json" "$d/$file.replay.json" >>"$rows"
  done
  say "LCM $LCM_URL on the loopback of a private network namespace; vislamd at"
  say "normal priority with its default options (mlockall), or (rows 'rt') with --rt-priority 80 --cpu 1;"
  say "LD_PRELOAD allocation counter. Step latency:"
  say "vislamd's, decode to publish; end-to-end: vislam-replay's, frame published to its pose received."
  say "Budget: the sensor period."
  say ""
  table daemon "$rows"
  end_section
}

# ---- 6. figures -----------------------------------------------------------------------------------
section_soak() {
  begin_section soak "8. Soak: vislamd fed the seed drives in a loop, over an hour of sensor time"
  local d="$OUT/soak" alloc loops=12 logs=() n
  mkdir -p "$d"
  if ! unshare --net true 2>/dev/null || ! command -v ip >/dev/null 2>&1; then
    say "SKIPPED: needs a private network namespace (unshare --net) and ip (iproute2)."
    end_section
    return
  fi
  need_data "the soak replays 0022, 0027 and 0034" || { end_section; return; }
  for n in 0022 0027 0034; do
    logs+=("$(logfor "$n")") || { end_section; return; }
  done
  [ "$QUICK" -eq 1 ] && loops=2
  alloc=$(find "$BUILD" -name 'libvl_alloc_counter.so' -print -quit 2>/dev/null)
  echo "unshare --net bash $SELF --soak-inner $BIN ${alloc:-''} $d $loops ${logs[*]}" >>"$SEC_CMDS"
  if ! unshare --net bash "$SELF" --soak-inner "$BIN" "$alloc" "$d" "$loops" "${logs[@]}" >"$d/inner.log" 2>&1; then
    warn "soak failed: $(tail -n 1 "$d/inner.log") (see $d)"
  fi
  say "One vislamd (default options, LD_PRELOAD allocation counter), fed by vislam-replay --lockstep --max"
  say "over LCM on a private loopback: 0022, 0027, 0034, then again, $loops times. Each new log is a new"
  say "timeline for the daemon (its time jumps back or days ahead), which the time policy handles."
  say ""
  table soak "$d/loops.tsv" "$d/vislamd.json"
  end_section
}

section_figures() {
  begin_section figures "6. Figures (trajectory, dead reckoning, map; animation)"
  local d="$OUT/figures" names=() name log gt
  mkdir -p "$d"
  : >"$d/runs.log"
  if need_data "0022, 0027, 0034"; then
    names=(0022 0027 0034)
  fi
  names+=(sample)
  for name in "${names[@]}"; do
    gt=()
    if [ "$name" = sample ]; then
      log=data/sample.lcmlog
      gt=(--gt data/sample_truth.tum)
    else
      log=$(logfor "$name") || continue
      [ "$name" = 0027 ] && [ -f "$GT07" ] && gt=(--gt "$GT07" --calib "$DATA/0027.npz")
    fi
    echo "# $name" >>"$SEC_CMDS"
    run "$d/runs.log" "$BIN/vislam-run" "$log" --trajectory "$d/$name.tum" --map "$d/$name.ply" --quiet &&
      run "$d/runs.log" "$BIN/vislam-run" "$log" --mode imu_only --trajectory "$d/${name}_dr.tum" --quiet &&
      run "$d/runs.log" tools/evaluate plot --estimate "$d/$name.tum" --dead-reckoning "$d/${name}_dr.tum" \
        --map "$d/$name.ply" "${gt[@]}" --out "$d/$name.png" &&
      run "$d/runs.log" tools/evaluate animate --estimate "$d/$name.tum" --dead-reckoning "$d/${name}_dr.tum" \
        --map "$d/$name.ply" "${gt[@]}" --out "$d/$name.gif"
    if [ -f "$d/$name.png" ] && [ -f "$d/$name.gif" ]; then
      say "- $name: $d/$name.png, $d/$name.gif$([ ${#gt[@]} -gt 0 ] && echo " (with ground truth)")"
    fi
  done
  end_section
}

# ---- 7. conditions: the accuracy test bed --------------------------------------------------------
# cond_log DIR TAG IN.npz CONDITIONS-OPTION...: the condition as an LCM log DIR/logs/TAG.lcmlog
# (and its summary TAG.summary.json); the intermediate .npz is removed (it is as big as the seed's)
cond_log() {
  local dir=$1 tag=$2 npz=$3
  shift 3
  local tmp="$dir/logs/$tag.npz" log="$dir/logs/$tag.lcmlog"
  rm -f "$log" "$dir/$tag.summary.json"
  run "$dir/runs.log" tools/conditions "$npz" "$tmp" "$@" --summary-json "$dir/$tag.summary.json" &&
    run "$dir/runs.log" tools/npz2lcm "$tmp" "$log"
  local rc=$?
  rm -f "$tmp"
  return $rc
}
# cond_cell DIR TAG LOG GT CALIB|"" [vislam-run option...]: dead reckoning and the default, and their ATE
cond_cell() {
  local dir=$1 tag=$2 log=$3 gt=$4 calib=$5
  shift 5
  local calib_args=() m opts
  [ -n "$calib" ] && calib_args=(--calib "$calib")
  for m in dr slam; do
    rm -f "$dir/${tag}_$m.ate.json"
    opts=(--mode imu_only)
    [ "$m" = slam ] && opts=("$@") # the extra options are for the default run
    run "$dir/runs.log" "$BIN/vislam-run" "$log" "${opts[@]}" --trajectory "$dir/${tag}_$m.tum" --quiet &&
      run "$dir/runs.log" tools/evaluate ate --estimate "$dir/${tag}_$m.tum" --gt "$gt" "${calib_args[@]}" \
        --json "$dir/${tag}_$m.ate.json"
  done
}
section_conditions() {
  begin_section conditions "7. Accuracy test bed: feature density x velocity noise x drive (ATE)"
  need_data "the test bed derives its conditions from the seed datasets" || { end_section; return; }
  local d="$OUT/conditions" rows ks vels v tag opts k name label truth cov_opt=()
  mkdir -p "$d/logs"
  : >"$d/runs.log"
  rows="$d/rows.tsv"
  : >"$rows"
  ks=(1 5 10 20)
  # file name|label|tools/conditions options (0.5 m/s, 0.05 rad/s: the given data's noise, per its README)
  vels=("given|given|" "given_x2|given x2|--velocity-noise-scale 2" "given_x4|given x4|--velocity-noise-scale 4"
    "clean|clean|--velocities clean --gt $GT07"
    "clean_n0.1|clean + 0.1x noise|--velocities clean --gt $GT07 --velocity-noise 0.05,0.005"
    "clean_n1|clean + 1x noise|--velocities clean --gt $GT07 --velocity-noise 0.5,0.05")
  if [ "$QUICK" -eq 1 ]; then
    ks=(1 10)
    vels=("${vels[0]}" "${vels[2]}" "${vels[3]}")
    say "(--quick: densities ${ks[*]} and three velocity conditions only)"
  fi
  # the covariance output for the consistency figure, where this build's vislam-run has it
  if "$BIN/vislam-run" --help 2>/dev/null | grep -q -- '--covariance'; then
    cov_opt=(--covariance "$d/0027_given_K1.cov")
  fi
  if [ -f "$GT07" ]; then
    for v in "${vels[@]}"; do
      IFS='|' read -r name label opts <<<"$v"
      for k in "${ks[@]}"; do
        tag="0027_${name}_K$k"
        note "0027 $label, 1 track in $k"
        echo "# 0027, velocities $label, keep every $k" >>"$SEC_CMDS"
        # shellcheck disable=SC2086 # opts is a list of words
        if cond_log "$d" "$tag" "$DATA/0027.npz" $opts --keep-every "$k" --seed 1; then
          if [ "$tag" = 0027_given_K1 ]; then
            cond_cell "$d" "$tag" "$d/logs/$tag.lcmlog" "$GT07" "$DATA/0027.npz" "${cov_opt[@]}"
          else
            cond_cell "$d" "$tag" "$d/logs/$tag.lcmlog" "$GT07" "$DATA/0027.npz"
          fi
        fi
        printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\n' 0027 "$label" "$k" "ground truth" "$d/$tag.summary.json" \
          "$d/${tag}_dr.ate.json" "$d/${tag}_slam.ate.json" >>"$rows"
      done
    done
  else
    say "SKIPPED (0027): no ground truth at $GT07"
  fi
  # No ground truth here for 0022 and 0034: the full-density default run is the pseudo-truth.
  local drive
  for drive in 0022 0034; do
    truth="$d/${drive}_given_K1_slam.tum"
    for k in "${ks[@]}"; do
      tag="${drive}_given_K$k"
      note "$drive given, 1 track in $k"
      echo "# $drive, given velocities, keep every $k (truth: the full-density default run)" >>"$SEC_CMDS"
      if [ "$k" -eq 1 ]; then
        cond_log "$d" "$tag" "$DATA/$drive.npz" --keep-every 1 &&
          run "$d/runs.log" "$BIN/vislam-run" "$d/logs/$tag.lcmlog" --trajectory "$truth" --quiet
      fi
      if [ ! -s "$truth" ]; then
        warn "$drive: no full-density default trajectory, so no pseudo-truth; its cells are n/a"
      elif [ "$k" -eq 1 ] || cond_log "$d" "$tag" "$DATA/$drive.npz" --keep-every "$k"; then
        cond_cell "$d" "$tag" "$d/logs/$tag.lcmlog" "$truth" ""
      fi
      printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$drive" given "$k" "pseudo-truth (vislam, all tracks)" \
        "$d/$tag.summary.json" "$d/${tag}_dr.ate.json" "$d/${tag}_slam.ate.json" >>"$rows"
    done
  done
  say "ATE: RMSE after a rigid SE(3) alignment (tools/evaluate ate). 0027 against KITTI odometry 07"
  say "(the clean-velocity conditions are cut to its 1101 poses). 0022 and 0034 have no ground truth"
  say "here: their truth is a PSEUDO-TRUTH, the vislam default run on all tracks (so its own cell is 0),"
  say "which measures how far fewer tracks move the estimate, not its accuracy. Velocities: given = the"
  say "dataset's (0.5 m/s, 0.05 rad/s noise); given xN = extra noise for N times that in total; clean ="
  say "from the ground truth (tools/conditions), then + noise at 0.1x or 1x the given level. Tracks kept:"
  say "ids j with j % K == 0. Obs. per frame: complete stereo observations per step in the input."
  say "Noise seed 1 everywhere: the cells of one velocity condition share their noise draw."
  say ""
  table conditions "$rows" --json "$d/conditions.json" --png "$d/conditions.png"
  say ""
  say "Figure: $d/conditions.png; numbers: $d/conditions.json."

  say ""
  say "### Consistency on 0027 (default, given velocities, all tracks)"
  say ""
  if [ ${#cov_opt[@]} -eq 0 ]; then
    say "SKIPPED: this build's vislam-run has no --covariance option."
  elif [ -s "$d/0027_given_K1.cov" ] && [ -s "$d/0027_given_K1_slam.tum" ]; then
    local a out
    for a in se3 none; do
      out="$d/consistency_0027.png"
      [ "$a" = none ] && out="$d/consistency_0027_noalign.png"
      : >"$d/consistency_$a.txt"
      run "$d/consistency_$a.txt" tools/evaluate consistency --estimate "$d/0027_given_K1_slam.tum" \
        --covariance "$d/0027_given_K1.cov" --gt "$GT07" --calib "$DATA/0027.npz" --align "$a" \
        --out "$out" --json "$d/consistency_0027_$a.json"
      say "Alignment $a ($out):"
      say ""
      say '```'
      grep -v '^wrote' "$d/consistency_$a.txt" | tee -a "$SEC_MD"
      say '```'
      say ""
    done
    say "The covariance is the filter's body-frame (right-perturbation) pose covariance; the error is"
    say "rotated into the body frame. The rigid alignment of the whole run (se3) spreads the drift over"
    say "time and inflates the early errors, when the filter is rightly sure of itself; none compares in"
    say "the estimator's start frame (the IMU at step 0), where its covariance is defined."
  fi
  end_section
}

# ---- 9. latency -----------------------------------------------------------------------------------
# vislam-latency: the step in-process and end to end through vislamd, with the jitter floor of the
# same run and the core's work per step; LCM on the loopback of a private network namespace.
section_latency() {
  begin_section latency "9. Latency (vislam-latency: in-process and through vislamd, with the jitter floor)"
  local d="$OUT/latency" rows log name netns=1 r label file extra
  mkdir -p "$d"
  rows="$d/rows.tsv"
  : >"$rows"
  : >"$d/runs.log"
  if [ "$QUICK" -eq 0 ] && [ "$HAVE_DATA" -eq 1 ] && log=$(logfor 0034); then
    name=0034
  else
    say "(--quick or no seed datasets: on the sample log instead of 0034)"
    log=data/sample.lcmlog
    name=sample
  fi
  if ! unshare --net true 2>/dev/null || ! command -v ip >/dev/null 2>&1; then
    say "(no private network namespace (unshare --net) or no ip: in-process only)"
    netns=0
  fi
  if [ ! -x "$BIN/vislam-latency" ]; then
    say "SKIPPED: $BIN/vislam-latency missing (build it first)."
    end_section
    return
  fi
  # As a robot would run it (SCHED_FIFO 80) where this is root; at normal priority otherwise.
  local sensor="sensor rate|--rate sensor"
  [ "$(id -u)" -eq 0 ] && sensor="sensor rate, SCHED_FIFO 80|--rate sensor --rt-priority 80"
  local runs=("$name, $sensor"
    "$name, as fast as possible x5|--rate max --passes 5"
    "$name, as fast as possible x5, --load|--rate max --passes 5 --load")
  say "Host: $(nproc) CPUs, $(sed -n 's/^model name\s*: //p' /proc/cpuinfo | head -n 1); load average before: $(cut -d' ' -f1-3 /proc/loadavg)."
  say ""
  for r in "${runs[@]}"; do
    IFS='|' read -r label extra <<<"$r"
    file=$(printf '%s' "$label" | tr -c 'A-Za-z0-9' '_')
    note "vislam-latency: $label"
    local cmd=("$BIN/vislam-latency" "$log" --json "$d/$file.json" --plot "$d/$file.png")
    # shellcheck disable=SC2206 # $extra holds separate options
    cmd+=($extra)
    if [ "$netns" -eq 1 ]; then
      cmd+=(--lcm-url "$LCM_URL")
      rec unshare --net bash -c 'ip link set lo up multicast on && ip route add 224.0.0.0/4 dev lo && exec "$@"' bash \
        "${cmd[@]}"
      VISLAM_PYTHON="$REPO_ROOT/$PY" unshare --net bash -c \
        'ip link set lo up multicast on && ip route add 224.0.0.0/4 dev lo && exec "$@"' bash "${cmd[@]}" \
        >>"$d/runs.log" 2>&1 || warn "vislam-latency ($label) failed (see $d/runs.log)"
    else
      VISLAM_PYTHON="$REPO_ROOT/$PY" run "$d/runs.log" "${cmd[@]}" --no-e2e
    fi
    printf '%s\t%s\n' "$label" "$d/$file.json" >>"$rows"
  done
  say "Step: vl_update through vl_session in vislam-latency's own process, pinned to CPU 1; end to end:"
  say "vislamd (CPU 1) and vislam-replay --lockstep (CPU 0) over LCM, frame published to pose received;"
  say "LCM overhead: per frame, end to end less vislamd's own step for it (vislamd --step-samples);"
  say "jitter floor: how late a 1 kHz clock_nanosleep probe on each CPU woke during the same run;"
  say "work: the core's own count (vl_get_work); budget: the log's frame period. Figures per run in"
  say "$d/*.json, CDFs in $d/*.png."
  say ""
  table latency "$rows"
  end_section
}

# ---- 10. reference implementations ---------------------------------------------------------------
# isam2_cell DIR TAG LOG GT CALIB|"" LABEL TRUTH-LABEL: vislam default and iSAM2 (online, smoothed,
# batch) on LOG, each scored against GT; a row for `reference.summary isam2`
isam2_cell() {
  local dir=$1 tag=$2 log=$3 gt=$4 calib=$5 label=$6 truth=$7 f
  local calib_args=()
  [ -n "$calib" ] && calib_args=(--calib "$calib")
  rm -f "$dir/$tag"_*.ate.json "$dir/${tag}_isam2.json"
  run "$dir/runs.log" "$BIN/vislam-run" "$log" --trajectory "$dir/${tag}_vislam.tum" --quiet
  run "$dir/runs.log" tools/reference/isam2 "$log" --trajectory "$dir/${tag}_online.tum" \
    --smoothed "$dir/${tag}_smoothed.tum" --batch "$dir/${tag}_batch.tum" --json "$dir/${tag}_isam2.json"
  for f in vislam online smoothed batch; do
    [ -f "$dir/${tag}_$f.tum" ] && run "$dir/runs.log" tools/evaluate ate --estimate "$dir/${tag}_$f.tum" \
      --gt "$gt" "${calib_args[@]}" --json "$dir/${tag}_$f.ate.json" >/dev/null
  done
  printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$label" "$truth" "$dir/${tag}_vislam.ate.json" "$dir/${tag}_online.ate.json" \
    "$dir/${tag}_smoothed.ate.json" "$dir/${tag}_batch.ate.json" "$dir/${tag}_isam2.json" >>"$dir/isam2_rows.tsv"
}
section_reference() {
  begin_section reference "10. Reference implementations: the NumPy filter, GTSAM's iSAM2"
  local d="$OUT/reference" names=(sample) name log
  mkdir -p "$d"
  : >"$d/runs.log"
  : >"$d/compare_rows.tsv"
  : >"$d/isam2_rows.tsv"
  if need_data "0027 and 0034 rows"; then
    names+=(0027)
    [ "$QUICK" -eq 0 ] && names+=(0034)
  fi
  for name in "${names[@]}"; do
    if [ "$name" = sample ]; then log=data/sample.lcmlog; else log=$(logfor "$name") || continue; fi
    rm -f "$d/${name}_compare.json"
    run "$d/runs.log" tools/reference/compare "$log" --max-landmarks 128 --json "$d/${name}_compare.json"
    printf '%s\t%s\n' "$name" "$d/${name}_compare.json" >>"$d/compare_rows.tsv"
  done
  say "The NumPy reference filter (tools/reference/vl_reference.py) beside vislam-run on the same log,"
  say "default configuration, window 128. Per-step time of the update: vislam-run --timing (histogram,"
  say "at most 6.25% high) and time.perf_counter around the reference's step (one BLAS thread); wall"
  say "times on a shared machine are indicative. Agreement over every frame (C poses printed to 1e-9)."
  say ""
  "$PY" -m reference.summary compare "$d/compare_rows.tsv" | tee -a "$SEC_MD"
  say ""
  if ! "$PY" -c "import gtsam" 2>/dev/null; then
    say "iSAM2: SKIPPED: the Python module gtsam is not installed (.venv/bin/pip install gtsam==4.3.0)."
    end_section
    return
  fi
  local sim_steps=1000
  [ "$QUICK" -eq 1 ] && sim_steps=300
  isam2_cell "$d" sample data/sample.lcmlog data/sample_truth.tum "" "sample (simulated, 200 steps)" truth
  if [ "$HAVE_DATA" -eq 1 ] && [ -f "$GT07" ] && log=$(logfor 0027); then
    isam2_cell "$d" 0027 "$log" "$GT07" "$DATA/0027.npz" 0027 "KITTI 07"
  fi
  run "$d/runs.log" "$BIN/vislam-sim" --out "$d/sim.lcmlog" --truth "$d/sim_truth.tum" --steps "$sim_steps" --quiet &&
    isam2_cell "$d" sim "$d/sim.lcmlog" "$d/sim_truth.tum" "" "vislam-sim, $sim_steps steps" truth
  run "$d/runs.log" "$BIN/vislam-sim" --realistic --out "$d/simr.lcmlog" --truth "$d/simr_truth.tum" \
    --steps "$sim_steps" --quiet &&
    isam2_cell "$d" simr "$d/simr.lcmlog" "$d/simr_truth.tum" "" "vislam-sim --realistic, $sim_steps steps" truth
  if [ "$QUICK" -eq 0 ] && [ "$HAVE_DATA" -eq 1 ] && log=$(logfor 0034); then
    # No ground truth: iSAM2's batch-refined trajectory is the yardstick for both.
    run "$d/runs.log" "$BIN/vislam-run" "$log" --trajectory "$d/0034_vislam.tum" --quiet
    run "$d/runs.log" tools/reference/isam2 "$log" --trajectory "$d/0034_online.tum" \
      --smoothed "$d/0034_smoothed.tum" --batch "$d/0034_batch.tum" --json "$d/0034_isam2.json"
    rm -f "$d"/0034_*.ate.json
    for name in vislam online smoothed; do
      run "$d/runs.log" tools/evaluate ate --estimate "$d/0034_$name.tum" --gt "$d/0034_batch.tum" \
        --json "$d/0034_$name.ate.json" >/dev/null
    done
    printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\n' 0034 "iSAM2 + batch (no truth)" "$d/0034_vislam.ate.json" \
      "$d/0034_online.ate.json" "$d/0034_smoothed.ate.json" - "$d/0034_isam2.json" >>"$d/isam2_rows.tsv"
  fi
  say "GTSAM's iSAM2 on the same measurements (tools/reference/isam2: stereo factors with a Huber loss,"
  say "tracks cut at the stale frames, between factors from the velocities). ATE RMSE (m) after a rigid"
  say "SE(3) alignment. online: each pose right after its frame (causal, like vislam); smoothed: the final"
  say "iSAM2 estimate; batch: after a Levenberg-Marquardt refinement of the whole graph."
  say ""
  "$PY" -m reference.summary isam2 "$d/isam2_rows.tsv" | tee -a "$SEC_MD"
  end_section
}

# ---- main -----------------------------------------------------------------------------------------
echo "== vislam benchmarks: ${SECTIONS[*]}$([ "$QUICK" -eq 1 ] && echo " (quick)")"
[ "$HAVE_DATA" -eq 0 ] && echo "   NOTE: no seed datasets in $DATA: the parts that need them are skipped"
for s in "${ALL_SECTIONS[@]}"; do
  case " ${SECTIONS[*]} " in *" $s "*) ;; *) continue ;; esac
  case $s in
    accuracy) section_accuracy ;;
    sweep) section_sweep ;;
    window) section_window ;;
    timing) section_timing ;;
    daemon) section_daemon ;;
    soak) section_soak ;;
    figures) section_figures ;;
    conditions) section_conditions ;;
    latency) section_latency ;;
    reference) section_reference ;;
  esac
done

TOTAL=$((SECONDS - T0))
{
  echo "# vislam benchmarks"
  echo
  echo "Generated by \`$SELF$([ "$QUICK" -eq 1 ] && echo " --quick")$([ ${#SECTIONS[@]} -ne ${#ALL_SECTIONS[@]} ] && printf ' --section %s' "${SECTIONS[@]}")\`"
  echo "on $(date -u '+%Y-%m-%d %H:%M UTC'), commit $(git rev-parse --short HEAD 2>/dev/null || echo '?')$(git diff --quiet HEAD -- core platform tools 2>/dev/null || echo ' (with local changes)')."
  echo "Host: $(nproc) CPUs, $(sed -n 's/^model name\s*: //p' /proc/cpuinfo | head -n 1), Linux $(uname -r)."
  echo "Build: $BUILD (Release, VL_NATIVE=${native:-?}, VL_MAX_LANDMARKS=${max_lm:-?}). Data: $DATA$([ "$HAVE_DATA" -eq 0 ] && echo " (absent)")."
  echo "Figures only: no number here is a pass/fail criterion. Total time ${TOTAL} s (${SECTION_TIMES[*]})."
  for s in "${ALL_SECTIONS[@]}"; do
    case " ${SECTIONS[*]} " in *" $s "*) echo; cat "$OUT/sections/$s.md" ;; esac
  done
} >"$REPORT"
echo
echo "== done in ${TOTAL} s (${SECTION_TIMES[*]}); $WARNINGS warning(s)"
echo "   report: $REPORT"
exit 0
