// Per-sample cost of the estimator (Hall array + filter), and of its parts, on
// the realistic motor after calibration. Google Benchmark; run from the repo root:
//   build/tests/bench_estimator [--benchmark_filter=...]
// Target: at most 1 us per sample per axis on the 2-core build machine.
#include <benchmark/benchmark.h>

#include <cstdio>
#include <vector>

#include "config/loader.hpp"
#include "core/identification.hpp"
#include "core/pipeline.hpp"
#include "sim/calibration_run.hpp"
#include "sim/sim_source.hpp"

namespace {

struct Fixture {
  ve::config::AxisConfig axis;
  ve::core::Calibration cal;
  std::vector<ve::core::RawSample> samples;  // multisine, 2 m/s, 10 m/s^2
  std::vector<double> truth_m;
  bool ok = false;
};

const Fixture& fixture() {
  static Fixture f = [] {
    Fixture f;
    auto loaded = ve::config::load_machine_file("config/machines/sim-realistic.yaml");
    if (!loaded.ok()) {
      std::fprintf(stderr, "run from the repository root: %s\n", ve::config::to_string(loaded.errors).c_str());
      return f;
    }
    f.axis = loaded.config.axes.at(0);
    std::vector<ve::core::ReferenceSegment> segments;
    std::string error;
    ve::core::IdentificationReport report;
    if (!ve::sim::record_calibration_run(f.axis.motor, f.axis.driver.sim, {}, segments, error) ||
        !ve::core::identify_with_reference(f.axis.motor, segments, {}, f.cal, report, error)) {
      std::fprintf(stderr, "calibration failed: %s\n", error.c_str());
      return f;
    }
    ve::sim::SimConfig cfg = f.axis.driver.sim;
    cfg.realtime = false;
    ve::sim::SimSource sim(f.axis.motor, cfg);
    ve::core::RawSample s;
    for (int i = 0; i < 40000 && sim.read(s) == ve::drivers::ReadStatus::ok; ++i) {
      f.samples.push_back(s);
      f.truth_m.push_back(sim.truth()->position_m);
    }
    f.ok = true;
    return f;
  }();
  return f;
}

ve::core::PipelineConfig pipeline_config(const Fixture& f) {
  ve::core::PipelineConfig pc;
  pc.motor = f.axis.motor;
  pc.sensors = f.cal.model;
  pc.calibrated = true;
  pc.start_position_m = f.axis.driver.sim.profile.start_m;
  return pc;
}

/// The whole per-sample path: Hall array, filter, status.
void BM_PipelineStep(benchmark::State& state) {
  const Fixture& f = fixture();
  if (!f.ok) {
    state.SkipWithError("no fixture");
    return;
  }
  ve::core::AxisPipeline pipeline(pipeline_config(f), f.cal.table);
  std::size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(pipeline.step(f.samples[i]));
    if (++i == f.samples.size()) {
      // Start over: a fresh pipeline, outside the timing.
      state.PauseTiming();
      pipeline = ve::core::AxisPipeline(pipeline_config(f), f.cal.table);
      i = 0;
      state.ResumeTiming();
    }
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations()));
}
BENCHMARK(BM_PipelineStep);

/// Block SF alone: one Hall solve from a guess near the truth.
void BM_HallSolve(benchmark::State& state) {
  const Fixture& f = fixture();
  if (!f.ok) {
    state.SkipWithError("no fixture");
    return;
  }
  ve::core::HallArray array(f.axis.motor, f.cal.table);
  std::size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(array.solve(f.samples[i], f.truth_m[i] + 1e-6, 0.0));
    if (++i == f.samples.size()) i = 0;
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations()));
}
BENCHMARK(BM_HallSolve);

/// Block K alone: predict + Hall update + accelerometer update.
void BM_FilterStep(benchmark::State& state) {
  const Fixture& f = fixture();
  if (!f.ok) {
    state.SkipWithError("no fixture");
    return;
  }
  ve::core::FusionFilter kf(f.axis.motor.sample_period_s(), f.axis.motor.filter, f.cal.model);
  kf.reset(f.truth_m[0], 1e-12, 0.0, true);
  std::size_t i = 0;
  bool applied = false;
  for (auto _ : state) {
    kf.predict();
    kf.update_hall(f.truth_m[i], 1e-13, 0.0, applied);
    kf.update_accel(f.samples[i].accel_mps2, 4e-4, 0.0, applied);
    benchmark::DoNotOptimize(kf.state());
    if (++i == f.samples.size()) {
      i = 0;
      kf.reset(f.truth_m[0], 1e-12, 0.0, true);
    }
  }
  state.SetItemsProcessed(static_cast<std::int64_t>(state.iterations()));
}
BENCHMARK(BM_FilterStep);

}  // namespace

BENCHMARK_MAIN();
