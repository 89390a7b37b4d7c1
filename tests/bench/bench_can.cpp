// Decoding cost per frame of the shipped SocketCAN layouts (issue 6).
#include <benchmark/benchmark.h>

#include <string>
#include <vector>

#include "socketcan/can_layout.hpp"
#include "config/can_layout_file.hpp"

using namespace ve::socketcan;

namespace {

CanLayout load(const char* rel) {
  CanLayout l;
  std::vector<ve::config::ConfigError> errors;
  if (!load_can_layout_file(std::string(VE_BENCH_SOURCE_DIR) + "/" + rel, l, errors)) std::abort();
  return l;
}

void decode_layout(benchmark::State& state, const char* rel) {
  const CanLayout l = load(rel);
  ve::core::RawSample in[kMaxSamplesPerFrame];
  for (int k = 0; k < l.samples_per_frame; ++k) {
    in[k].hall_count = 4;
    in[k].hall_v = {1.0 + 0.01 * k, 2.0, 3.0, 4.0};
    in[k].accel_mps2 = -3.0 + k;
  }
  FrameBytes f;
  encode(l, in, 77, 0.0, f);
  DecodedFrame d;
  for (auto _ : state) {
    benchmark::DoNotOptimize(decode(l, f, d));
    benchmark::DoNotOptimize(d.samples[0].hall_v[0]);
  }
  state.SetItemsProcessed(state.iterations() * l.samples_per_frame);
  state.SetLabel("ns/frame; items = samples");
}

void encode_layout(benchmark::State& state, const char* rel) {
  const CanLayout l = load(rel);
  ve::core::RawSample in[kMaxSamplesPerFrame];
  for (int k = 0; k < l.samples_per_frame; ++k) {
    in[k].hall_count = 4;
    in[k].hall_v = {1.0, 2.0, 3.0, 4.0};
  }
  FrameBytes f;
  std::uint64_t seq = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(encode(l, in, ++seq, 0.0, f));
    benchmark::DoNotOptimize(f.data[0]);
  }
  state.SetItemsProcessed(state.iterations() * l.samples_per_frame);
}

}  // namespace

BENCHMARK_CAPTURE(decode_layout, classic_4hall, "config/can/classic-4hall.yaml");
BENCHMARK_CAPTURE(decode_layout, fd_4hall_x8, "config/can/fd-4hall-x8.yaml");
BENCHMARK_CAPTURE(encode_layout, classic_4hall, "config/can/classic-4hall.yaml");
BENCHMARK_CAPTURE(encode_layout, fd_4hall_x8, "config/can/fd-4hall-x8.yaml");
BENCHMARK_MAIN();
