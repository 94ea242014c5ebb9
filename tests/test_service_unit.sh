#!/usr/bin/env bash
# The systemd unit of vislamd as configured for the install prefix, checked offline. Run by CTest:
#
#   tests/test_service_unit.sh UNIT BINDIR VISLAMD
#
# UNIT is the configured tools/vislamd/vislamd.service (build tree), BINDIR the install prefix's
# bin directory it must start vislamd from, VISLAMD the built program (`systemd-analyze verify`
# needs the ExecStart program to exist, so it verifies a copy that starts the built one).
# Checks: ExecStart under BINDIR, Type=notify with a watchdog, `systemd-analyze security
# --offline=yes` exposure below 6.0, `systemd-analyze verify` without a complaint.
# Exit 77 (CTest skip) without systemd-analyze (Debian package systemd) or its --offline option
# (systemd 250 and later).
set -uo pipefail

if [ $# -ne 3 ]; then
  echo "usage: $0 UNIT BINDIR VISLAMD" >&2
  exit 2
fi
UNIT=$1
BINDIR=$2
VISLAMD=$3
source "$(dirname "$0")/support/vl_record.sh" # check, eq, le

if ! command -v systemd-analyze >/dev/null 2>&1; then
  echo "SKIP: systemd-analyze not found (Debian package systemd)"
  exit 77
fi
OUT=$(mktemp -d /tmp/vislam_test_unit.XXXXXX)
trap 'rm -rf "$OUT"' EXIT
FAILS=0

check "ExecStart runs $BINDIR/vislamd" grep -q "^ExecStart=$BINDIR/vislamd " "$UNIT"
check "Type=notify" grep -qx 'Type=notify' "$UNIT"
check "a watchdog (WatchdogSec=)" grep -q '^WatchdogSec=[1-9]' "$UNIT"
check "real-time capabilities kept (CAP_SYS_NICE CAP_IPC_LOCK)" \
  grep -qx 'AmbientCapabilities=CAP_SYS_NICE CAP_IPC_LOCK' "$UNIT"

# The unit under its own name: systemd-analyze names the service after the file.
cp "$UNIT" "$OUT/vislamd.service"
if ! systemd-analyze security --offline=yes "$OUT/vislamd.service" >"$OUT/security.txt" 2>&1; then
  if grep -q -- "--offline" "$OUT/security.txt"; then
    echo "SKIP: this systemd-analyze has no --offline (systemd 250 and later)"
    exit 77
  fi
fi
EXPOSURE=$(sed -n 's/.*Overall exposure level for vislamd.service: \([0-9.]*\).*/\1/p' "$OUT/security.txt")
grep -E '✗' "$OUT/security.txt" | sed 's/^/      /'
check "systemd-analyze security: exposure ${EXPOSURE:-missing} < 6.0" \
  awk -v e="${EXPOSURE:-99}" 'BEGIN { exit !(e < 6.0) }'

sed "s#^ExecStart=$BINDIR/vislamd #ExecStart=$VISLAMD #" "$UNIT" >"$OUT/vislamd.service"
systemd-analyze verify "$OUT/vislamd.service" >"$OUT/verify.txt" 2>&1
RC=$?
sed 's/^/      /' "$OUT/verify.txt"
check "systemd-analyze verify: exit 0 and nothing said about the unit" \
  eq "$RC/$(grep -c 'vislamd.service' "$OUT/verify.txt")" "0/0"

echo "== $FAILS failure(s)"
[ "$FAILS" -eq 0 ]
