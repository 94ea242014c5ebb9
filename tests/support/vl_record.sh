# Shared by the shell tests (sourced): entering a private network namespace and the state of a test
# there, recording the daemon's outputs and synchronizing on them, and the checks they make. The
# recording helpers need $INSPECT (vl_log_inspect) and begin_netns_test's $URL, $OUT and PIDS.
#
# Synchronization is on what the daemon publishes, never on guessed delays: a recording is read
# back with vl_log_inspect while lcm-logger writes it. --flush-interval=1 makes each event reach
# the file as it is written (the default flushes only when an event comes 100 ms after the last
# flush, so a final status could sit in the logger's buffer until it exits).

# enter_private_netns SCRIPT ARGS...: outside a namespace, checks what the test needs and runs
# SCRIPT again inside `unshare --net` (exit 77, CTest's skip, when it cannot); inside, brings up a
# multicast loopback for LCM. Returns only inside the namespace.
enter_private_netns() {
  if [ -z "${VL_TEST_IN_NETNS:-}" ]; then
    if ! command -v lcm-logger >/dev/null 2>&1; then
      echo "SKIP: lcm-logger not found (Debian package liblcm-bin)"
      exit 77
    fi
    if ! unshare --net true 2>/dev/null; then
      echo "SKIP: cannot create a private network namespace (unshare --net needs root or user namespaces);"
      echo "      run this test as root, or in a container that allows it"
      exit 77
    fi
    exec unshare --net env VL_TEST_IN_NETNS=1 bash "$@"
  fi
  ip link set lo up multicast on || { echo "SKIP: cannot bring up lo in the namespace"; exit 77; }
  ip route add 224.0.0.0/4 dev lo || { echo "SKIP: cannot add a multicast route in the namespace"; exit 77; }
}

# begin_netns_test NAME: inside the namespace, the state every daemon test keeps: URL (LCM on the
# private loopback), OUT (a new directory, removed at exit unless a check failed), FAILS, and PIDS,
# the processes killed (SIGKILL) at exit.
begin_netns_test() {
  URL='udpm://239.255.76.67:7667?ttl=0'
  OUT=$(mktemp -d "/tmp/vislam_test_$1.XXXXXX")
  FAILS=0
  PIDS=()
  trap end_netns_test EXIT
}

end_netns_test() {
  local p
  for p in "${PIDS[@]}"; do
    kill -KILL "$p" 2>/dev/null || true
  done
  if [ "$FAILS" -eq 0 ]; then
    rm -rf "$OUT"
  else
    echo "outputs kept in $OUT"
  fi
}

# record_start NAME CHANNELS: lcm-logger into $OUT/NAME.lcmlog; its pid in $LOGGER.
record_start() {
  lcm-logger --lcm-url="$URL" --channel="$2" --flush-interval=1 -q -f "$OUT/$1.lcmlog" &
  LOGGER=$!
  PIDS+=("$LOGGER")
}

# wait_recorded LOG KEY MIN SECONDS: until vl_log_inspect's KEY >= MIN in LOG; 1 (and a line) on timeout.
wait_recorded() {
  local deadline=$((SECONDS + $4)) v
  while [ "$SECONDS" -le "$deadline" ]; do
    if [ -s "$1" ]; then
      v=$("$INSPECT" "$1" 2>/dev/null | awk -v k="$2" '$1 == k { print $2 }' || true)
      if [ -n "$v" ] && [ "$v" -ge "$3" ] 2>/dev/null; then
        return 0
      fi
    fi
    sleep 0.05 # the poll period, not a guess at when something happens
  done
  echo "      timed out waiting for $2 >= $3 in $1"
  return 1
}

# wait_line FILE PATTERN SECONDS: until FILE has a line matching PATTERN; 1 (and a line) on timeout.
wait_line() {
  local deadline=$((SECONDS + $3))
  while [ "$SECONDS" -le "$deadline" ]; do
    grep -q "$2" "$1" 2>/dev/null && return 0
    sleep 0.05 # the poll period, not a guess at when something happens
  done
  echo "      timed out waiting for '$2' in $1"
  return 1
}

# wait_exit PID SECONDS: waits for PID to end; its exit status in $WAIT_RC (124 on timeout).
wait_exit() {
  local i
  for ((i = 0; i < $2 * 10; i++)); do
    if ! kill -0 "$1" 2>/dev/null; then
      WAIT_RC=0
      wait "$1" || WAIT_RC=$?
      return 0
    fi
    sleep 0.1 # the poll period of a bounded wait for the process's end
  done
  kill -KILL "$1" 2>/dev/null || true
  wait "$1" 2>/dev/null || true
  WAIT_RC=124
}

# record_stop NAME: SIGTERM to $DAEMON (its exit status in $WAIT_RC), then the logger once the
# recording holds a status stamped after the SIGTERM: the daemon's final one.
record_stop() {
  local t_term rc
  t_term=$(date +%s%6N)
  kill -TERM "$DAEMON" 2>/dev/null || true
  wait_exit "$DAEMON" 10
  rc=$WAIT_RC
  wait_recorded "$OUT/$1.lcmlog" status.last.utime "$t_term" 5 || true
  kill -INT "$LOGGER" 2>/dev/null || true
  wait_exit "$LOGGER" 5
  WAIT_RC=$rc
}

# ---- checks: each prints ok/FAIL and counts failures in $FAILS -------------------------------------
check() { # check DESCRIPTION COMMAND...
  local what=$1
  shift
  if "$@"; then
    echo "ok:   $what"
  else
    echo "FAIL: $what"
    FAILS=$((FAILS + 1))
  fi
}
value() { # value FILE KEY -> the value of "KEY value" in FILE
  awk -v k="$2" '$1 == k { print $2; found = 1 } END { if (!found) print "missing" }' "$1"
}
eq() { [ "$1" = "$2" ] || { echo "      expected '$2', got '$1'"; return 1; }; }
le() { [ "$1" -le "$2" ] 2>/dev/null || { echo "      expected $1 <= $2"; return 1; }; }
ge() { [ "$1" -ge "$2" ] 2>/dev/null || { echo "      expected $1 >= $2"; return 1; }; }
