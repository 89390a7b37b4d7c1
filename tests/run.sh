#!/usr/bin/env bash
# The test command: set up, build, fuzz every parser for a bounded time, run the suite
# under ASan+UBSan, then again under ThreadSanitizer, then run every test
# (unit, real-process DDS, Cyclone interop, SocketCAN in a VM).
# A failing stage stops the run there, its report last.
set -euo pipefail
cd "$(dirname "$0")/.."
stage() {
  local name="$1" t0=$SECONDS
  shift
  echo "== $name"
  "$@"
  echo "== $name: done in $((SECONDS - t0)) s"
}
stage setup bash deploy/setup.sh
stage build bash deploy/build.sh
# Every parser under libFuzzer (ASan + UBSan) for a bounded time.
stage fuzz bash tests/fuzz/run.sh "${VE_FUZZ_SECONDS:-20}"
# The unit, integration and install tests again in build-asan, under AddressSanitizer +
# UndefinedBehaviorSanitizer (tests/sanitizers/run.sh says what is left out, and why).
stage "ASan+UBSan test suite" bash tests/sanitizers/run.sh asan
# The unit, integration and install tests again in build-tsan, under ThreadSanitizer
# (tests/sanitizers/run.sh says what is left out, and why).
stage "TSan test suite" bash tests/sanitizers/run.sh tsan
# Shared-memory segments left by a crashed DDS process would confuse the next run.
fastdds shm clean >/dev/null 2>&1 || true
cd build
ctest --output-on-failure --timeout 300 "$@"
