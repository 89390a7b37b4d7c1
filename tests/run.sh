#!/usr/bin/env bash
# The test command: set up, build, fuzz every parser for a bounded time, then run
# every test (unit, real-process DDS, Cyclone interop, SocketCAN in a VM).
set -euo pipefail
cd "$(dirname "$0")/.."
bash deploy/setup.sh
bash deploy/build.sh
# Every parser under libFuzzer (ASan + UBSan) for a bounded time.
bash tests/fuzz/run.sh "${VE_FUZZ_SECONDS:-20}"
# Shared-memory segments left by a crashed DDS process would confuse the next run.
fastdds shm clean >/dev/null 2>&1 || true
cd build
ctest --output-on-failure --timeout 300 "$@"
