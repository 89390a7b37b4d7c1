#!/usr/bin/env bash
# Configures and builds into ./build (Ninja, RelWithDebInfo). Extra arguments go to cmake's configure step.
# The tests are built unless an argument says otherwise (-DVE_BUILD_TESTS=OFF, as the demo does):
# a tree configured without them by the demo gets them back on the next plain build.
set -euo pipefail
cd "$(dirname "$0")/.."
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DVE_BUILD_TESTS=ON "$@" >/dev/null
cmake --build build --parallel "$(nproc)"
