#!/usr/bin/env bash
# Builds the fuzz targets with clang (ASan + UBSan + libFuzzer) and runs each for
# a bounded time on its seed corpus. Any crash, leak or sanitizer report fails.
#   tests/fuzz/run.sh [SECONDS_PER_TARGET]   (default 20)
set -euo pipefail
cd "$(dirname "$0")/../.."
SECONDS_PER_TARGET="${1:-20}"
BUILD=build-fuzz
CC=clang CXX=clang++ cmake -S . -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DVE_FUZZ=ON \
  -DVE_BUILD_BENCHMARKS=OFF >/dev/null
targets=(fuzz_machine_config fuzz_calibration_file fuzz_raw_log fuzz_can_layout fuzz_can_frame fuzz_kept_position
  fuzz_command_line)
cmake --build "$BUILD" --target "${targets[@]}"
status=0
for t in "${targets[@]}"; do
  corpus_name="${t#fuzz_}"
  case "$t" in
    fuzz_machine_config) seeds=tests/fuzz/corpus/config ;;
    fuzz_calibration_file) seeds=tests/fuzz/corpus/calibration ;;
    fuzz_raw_log) seeds=tests/fuzz/corpus/raw_log ;;
    fuzz_can_layout) seeds=tests/fuzz/corpus/can_layout ;;
    fuzz_can_frame) seeds=tests/fuzz/corpus/can_frame ;;
    fuzz_kept_position) seeds=tests/fuzz/corpus/kept_position ;;
    fuzz_command_line) seeds=tests/fuzz/corpus/command_line ;;
  esac
  work="$BUILD/corpus/$corpus_name"
  mkdir -p "$work"
  echo "fuzz: $t for ${SECONDS_PER_TARGET}s"
  if ! "$BUILD/tests/$t" -max_total_time="$SECONDS_PER_TARGET" -max_len=65536 -timeout=10 \
      -artifact_prefix="$BUILD/" "$work" "$seeds" >"$BUILD/$t.log" 2>&1; then
    echo "fuzz: $t FAILED; last lines of $BUILD/$t.log:"
    tail -n 30 "$BUILD/$t.log"
    status=1
  else
    grep -E "^#[0-9]+.*(DONE|pulse)" "$BUILD/$t.log" | tail -n 1 || true
  fi
done
exit $status
