#!/usr/bin/env bash
# The test command: set up, build, run every test (unit and real-process DDS integration).
set -euo pipefail
cd "$(dirname "$0")/.."
bash deploy/setup.sh
bash deploy/build.sh
# Shared-memory segments left by a crashed DDS process would confuse the next run.
fastdds shm clean >/dev/null 2>&1 || true
cd build
ctest --output-on-failure --timeout 300 "$@"
