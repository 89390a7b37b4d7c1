#!/bin/sh
# Interop test: Fast DDS publisher (`virtual-encoder run`, standstill machine at
# 0.3 m, axis id 1) -> Cyclone DDS subscriber (tests/interop/cyclone_subscriber.c).
#   run_interop.sh VIRTUAL_ENCODER CYCLONE_SUBSCRIBER MACHINE_YAML DOMAIN
set -u
VE="$1"; SUB="$2"; MACHINE="$3"; DOMAIN="$4"
LOG="${TMPDIR:-/tmp}/ve_interop_run_$$.log"

"$VE" run --config "$MACHINE" --domain "$DOMAIN" --duration 30 --wait-for-subscriber 20 >"$LOG" 2>&1 &
PID=$!
cleanup() { kill "$PID" 2>/dev/null; wait "$PID" 2>/dev/null; }
trap cleanup EXIT INT TERM

"$SUB" "$DOMAIN" 4000 25 1 0.3 5e-6
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
