#!/usr/bin/env bash
# vislamd's systemd notifications (sd_notify over NOTIFY_SOCKET), without systemd. Run by CTest:
#
#   tests/test_notify.sh BIN_DIR NOTIFY_LISTEN SOURCE_DIR
#
# tests/support/vl_notify_listen plays the service manager: it binds the datagram socket that
# NOTIFY_SOCKET names and records what arrives. vislamd runs with WATCHDOG_USEC=2 s in a private
# network namespace (as tests/test_daemon.sh), data/sample.lcmlog is replayed into it in
# lockstep, then it gets SIGTERM. Checks: READY=1 once, before any WATCHDOG=1; WATCHDOG=1 at
# least every WATCHDOG_USEC (what systemd enforces) and none after STOPPING=1; a STATUS= line
# that tracks the replayed frames; STOPPING=1 once; exit 0.
# Exit 77 (CTest skip) when a private network namespace or lcm-logger is unavailable.
# No -e: every check runs and is reported; the exit status counts the failed ones.
set -uo pipefail

if [ $# -ne 3 ]; then
  echo "usage: $0 BIN_DIR NOTIFY_LISTEN SOURCE_DIR" >&2
  exit 2
fi
BIN=$1
LISTEN=$2
SRC=$3
LOG="$SRC/data/sample.lcmlog"

# shellcheck source=support/vl_record.sh
source "$(dirname "$0")/support/vl_record.sh"
enter_private_netns "$0" "$@"

# ---- inside the namespace ---------------------------------------------------------------------
begin_netns_test notify
START=$SECONDS
WATCHDOG_MS=2000

"$LISTEN" "$OUT/notify.sock" 30 >"$OUT/notify.txt" &
LISTENER=$!
PIDS+=("$LISTENER")
for _ in $(seq 100); do # the listener's bind, polled
  [ -S "$OUT/notify.sock" ] && break
  sleep 0.05
done

NOTIFY_SOCKET="$OUT/notify.sock" WATCHDOG_USEC=$((WATCHDOG_MS * 1000)) \
  "$BIN/vislamd" --lcm-url "$URL" --no-mlock --quiet 2>"$OUT/daemon.err" &
DAEMON=$!
PIDS+=("$DAEMON")
"$BIN/vislam-replay" "$LOG" --lcm-url "$URL" --lockstep --speed 10 --timeout-ms 5000 \
  --wait-for VISLAM_STATUS --wait-timeout-ms 20000 --quiet 2>"$OUT/replay.err"
check "replay into the notifying daemon: every frame's pose came back" eq $? 0
# The STATUS= line follows the once-a-second status: wait (bounded) until it has all 200 frames.
for _ in $(seq 60); do
  grep -q 'STATUS=tracking: imu 200 frames 200' "$OUT/notify.txt" && break
  sleep 0.05
done
kill -TERM "$DAEMON"
wait_exit "$DAEMON" 10
check "vislamd exits 0 on SIGTERM" eq "$WAIT_RC" 0
wait_exit "$LISTENER" 10
grep '^msg' "$OUT/notify.txt" | head -n 3 | sed 's/^/      /'
grep '^msg' "$OUT/notify.txt" | tail -n 2 | sed 's/^/      /'
N=$OUT/notify.txt
check "READY=1 exactly once" eq "$(value "$N" ready)" 1
check "no WATCHDOG=1 before READY=1" eq "$(value "$N" watchdog.before_ready)" 0
check "WATCHDOG=1 sent (at least 2, every half period)" ge "$(value "$N" watchdog)" 2
check "no gap between READY=1, each WATCHDOG=1 and STOPPING=1 over WATCHDOG_USEC ($(value "$N" watchdog.max_gap_ms) ms)" \
  le "$(value "$N" watchdog.max_gap_ms)" "$WATCHDOG_MS"
check "STOPPING=1 exactly once, and no WATCHDOG=1 after it" \
  eq "$(value "$N" stopping)/$(value "$N" watchdog.after_stopping)" "1/0"
check "a STATUS= line once tracking: every replayed sample and frame counted" \
  grep -q 'STATUS=tracking: imu 200 frames 200 poses 400' "$N"
check "the last STATUS= says why it stops" grep -q '^status.last stopping (SIGTERM)' "$N"
check "every line is KEY=VALUE" eq "$(value "$N" unknown)" 0

# Without NOTIFY_SOCKET nothing is sent and nothing changes: the daemon test covers that run.
echo "== $((SECONDS - START)) s, $FAILS failure(s)"
[ "$FAILS" -eq 0 ]
