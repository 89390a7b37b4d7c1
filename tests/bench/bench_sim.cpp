// Cost of the simulator per sample: it must stay far below the 250 us period at
// 4 kHz so that offline runs (record, accuracy sweeps) go many times real time.
#include <benchmark/benchmark.h>

#include "core/motor.hpp"
#include "sim/motion_profile.hpp"
#include "sim/sim_source.hpp"

namespace {

void BM_ProfileAt(benchmark::State& state) {
  ve::sim::MotionProfileConfig cfg;
  cfg.kind = static_cast<ve::sim::MotionProfileConfig::Kind>(state.range(0));
  const auto profile = ve::sim::MotionProfile::create(cfg, 1.0);
  if (!profile) {
    state.SkipWithError("profile");
    return;
  }
  double t = 0.0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(profile->at(t));
    t += 0.00025;
  }
  state.SetLabel(ve::sim::kind_name(cfg.kind));
}
BENCHMARK(BM_ProfileAt)->DenseRange(0, 4);

void BM_SimRead(benchmark::State& state) {
  ve::core::MotorConfig motor;
  ve::sim::SimConfig cfg;
  cfg.realtime = false;
  if (state.range(0) != 0) {  // imperfect track: the piecewise warp instead of one sin()
    cfg.imperfections.magnet_strength_std = 0.01;
    cfg.imperfections.magnet_placement_std_m = 20e-6;
    cfg.imperfections.hall_delay_s = 50e-6;
  }
  ve::sim::SimSource src(motor, cfg);
  ve::core::RawSample s;
  for (auto _ : state) {
    if (src.read(s) != ve::drivers::ReadStatus::ok) {
      state.SkipWithError("read");
      break;
    }
    benchmark::DoNotOptimize(s);
  }
  state.SetLabel(state.range(0) != 0 ? "imperfect" : "ideal");
}
BENCHMARK(BM_SimRead)->Arg(0)->Arg(1);

}  // namespace

BENCHMARK_MAIN();
