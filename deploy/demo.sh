#!/usr/bin/env bash
# The front door: set up, build, then run the virtual encoder on the built-in
# simulated motor and watch it live from a second process over DDS.
#   deploy/demo.sh [SECONDS]     (default: until Ctrl-C)
# VE_DEMO_DOMAIN=N (0..232, default 42) is the DDS domain the demo's two processes use.
set -euo pipefail
cd "$(dirname "$0")/.."
DURATION="${1:-0}"
DOMAIN="${VE_DEMO_DOMAIN:-42}"
# Refused before the set-up and the build, not minutes later by the program.
if ! [[ "$DOMAIN" =~ ^[0-9]{1,3}$ ]] || [ "$((10#$DOMAIN))" -gt 232 ]; then
  echo "demo: VE_DEMO_DOMAIN='$DOMAIN' is not a DDS domain id: expected a whole number 0..232" >&2
  exit 2
fi
DOMAIN="$((10#$DOMAIN))"
if ! [[ "$DURATION" =~ ^[0-9]+([.][0-9]+)?$ ]]; then
  echo "demo: '$DURATION' is not a number of seconds (usage: deploy/demo.sh [SECONDS]; 0 or none: until Ctrl-C)" >&2
  exit 2
fi

# Only what building and running need (no test toolchains), and the product without its tests.
bash deploy/setup.sh --run
bash deploy/build.sh -DVE_BUILD_TESTS=OFF

BIN=./build/virtual-encoder
mkdir -p build/demo
echo "demo: starting 'virtual-encoder run' (built-in simulator machine) on DDS domain $DOMAIN; log in build/demo/run.log"
"$BIN" run --domain "$DOMAIN" >build/demo/run.log 2>&1 &
RUN_PID=$!
cleanup() {
  kill -TERM "$RUN_PID" 2>/dev/null || true
  wait "$RUN_PID" 2>/dev/null || true
  echo "demo: publisher stopped; its log:"
  tail -n 4 build/demo/run.log
}
trap cleanup EXIT

echo "demo: 'virtual-encoder monitor' subscribes from a second process"
"$BIN" monitor --domain "$DOMAIN" --duration "$DURATION"
