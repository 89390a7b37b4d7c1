#!/bin/sh
# Interop test: Fast DDS publisher (`virtual-encoder run`, standstill machine at
# 0.3 m, axis id 1) -> Cyclone DDS subscriber (tests/interop/cyclone_subscriber.c).
#   run_interop.sh VIRTUAL_ENCODER CYCLONE_SUBSCRIBER MACHINE_YAML
# The DDS domain is one no other test on this host holds (tests/dds_domain.sh); both
# processes inherit its lock, are stopped when this script ends, and are killed by the
# kernel if it dies first (setpriv --pdeathsig).
set -u
VE="$1"; SUB="$2"; MACHINE="$3"
. "$(dirname "$0")/../dds_domain.sh"
ve_reserve_dds_domain || exit 1
DOMAIN=$VE_DDS_DOMAIN
LOG="${TMPDIR:-/tmp}/ve_interop_run_$$.log"
ENDS_WITH_US=""
if setpriv --pdeathsig KILL true 2>/dev/null; then ENDS_WITH_US="setpriv --pdeathsig KILL"; fi

$ENDS_WITH_US "$VE" run --config "$MACHINE" --domain "$DOMAIN" --duration 30 --wait-for-subscriber 20 >"$LOG" 2>&1 &
PID=$!
cleanup() { kill "$PID" 2>/dev/null; wait "$PID" 2>/dev/null; }
trap cleanup EXIT INT TERM

$ENDS_WITH_US "$SUB" "$DOMAIN" 4000 25 1 0.3 5e-6
RC=$?
kill -TERM "$PID" 2>/dev/null
wait "$PID"
PUB_RC=$?
trap - EXIT
echo "--- virtual-encoder run (exit $PUB_RC) ---"
cat "$LOG"
rm -f "$LOG"
if [ "$RC" -ne 0 ]; then echo "FAIL: the Cyclone DDS subscriber did not receive correct samples"; exit 1; fi
if [ "$PUB_RC" -ne 0 ]; then echo "FAIL: virtual-encoder run exited with $PUB_RC"; exit 1; fi
echo "PASS: Cyclone DDS received correct ve::dds::EncoderState samples from Fast DDS"
