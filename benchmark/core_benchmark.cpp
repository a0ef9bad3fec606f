// Google Benchmark for the core's hot paths. Results and the command are in BENCHMARKS.md.
//   One scan: 1081 beams over 270 degrees, every beam a hit at 29.97 m (the worst case of a
//   30 m sensor), 0.05 m cells.

#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdint>
#include <vector>

#include "dynamic_occupancy_grid/core/mapper.h"
#include "dynamic_occupancy_grid/core/traversal.h"

namespace dog = dynamic_occupancy_grid::core;

namespace {

constexpr int kBeams = 1081;
constexpr double kFieldOfView = 1.5 * M_PI;
constexpr double kRange = 29.97;
constexpr double kResolution = 0.05;

dog::Scan makeScan(double stamp_s) {
  dog::Scan scan;
  scan.stamp_s = stamp_s;
  scan.laser_pose = dog::Pose2D{0.013, -0.021, 0.1};
  scan.angle_min_rad = -kFieldOfView / 2.0;
  scan.angle_increment_rad = kFieldOfView / (kBeams - 1);
  scan.range_min_m = 0.1;
  scan.range_max_m = 30.0;
  scan.ranges_m.assign(kBeams, static_cast<float>(kRange));
  return scan;
}

dog::MapperConfig benchmarkConfig() {
  dog::MapperConfig config;
  config.resolution_m = kResolution;
  return config;
}

// The traversal alone: every cell of every beam visited once, nothing stored. The floor any
// scan insertion has to pay.
void BM_ScanTraversal(benchmark::State& state) {
  const dog::Scan scan = makeScan(0.0);
  std::int64_t visits = 0;
  for (auto _ : state) {
    std::int64_t sum = 0;
    for (int i = 0; i < kBeams; ++i) {
      const double angle = scan.laser_pose.yaw_rad + scan.angle_min_rad + i * scan.angle_increment_rad;
      const double u0 = scan.laser_pose.x_m / kResolution;
      const double v0 = scan.laser_pose.y_m / kResolution;
      const dog::CellXY end = dog::traverseSegment(
          u0, v0, u0 + std::cos(angle) * kRange / kResolution, v0 + std::sin(angle) * kRange / kResolution,
          [&sum, &visits](std::int32_t x, std::int32_t y) {
            sum += x ^ y;
            ++visits;
          });
      sum += end.x;
      ++visits;
    }
    benchmark::DoNotOptimize(sum);
  }
  state.SetItemsProcessed(visits);  // cell visits per second
  state.SetLabel("1081 beams, 270 deg, 30 m, 0.05 m cells");
}
BENCHMARK(BM_ScanTraversal)->Unit(benchmark::kMicrosecond);

// One scan into the mapper within an open step: traversal + per-scan de-duplication + hit /
// miss counting in the tiles (the map already holds the area, as in steady operation).
void BM_ScanIntegrate(benchmark::State& state) {
  dog::Mapper mapper(benchmarkConfig());
  dog::Scan scan = makeScan(0.0);
  mapper.integrate(scan);
  std::size_t beams = 0;
  for (auto _ : state) {
    const dog::ScanResult result = mapper.integrate(scan);
    beams += result.beams_hit;
  }
  benchmark::DoNotOptimize(beams);
  state.SetLabel("area already allocated, step stays open");
}
BENCHMARK(BM_ScanIntegrate)->Unit(benchmark::kMicrosecond);

// Applying a step: every cell touched by one scan is brought over its gap, filtered and
// its baseline updated. Reported per touched cell.
void BM_StepUpdate(benchmark::State& state) {
  dog::Mapper mapper(benchmarkConfig());
  double stamp = 0.0;
  std::size_t touched = 0;
  for (auto _ : state) {
    state.PauseTiming();
    const dog::Scan scan = makeScan(stamp);
    stamp += 3.0;  // a gap of two unobserved steps before each applied step
    mapper.integrate(scan);
    mapper.takeChangedCells();
    state.ResumeTiming();
    mapper.finishStep();
    state.PauseTiming();
    const dog::CellBox changed = mapper.takeChangedCells();
    benchmark::DoNotOptimize(changed);
    state.ResumeTiming();
  }
  // Cells one scan touches (every iteration touches the same set).
  {
    dog::Mapper counter(benchmarkConfig());
    counter.integrate(makeScan(0.0));
    counter.finishStep();
    const dog::CellBox box = counter.grid().bounds();
    for (std::int32_t y = box.min_y; y <= box.max_y; ++y) {
      for (std::int32_t x = box.min_x; x <= box.max_x; ++x) touched += counter.grid().cell(x, y) ? 1 : 0;
    }
  }
  state.counters["touched_cells"] = static_cast<double>(touched);
  // items_per_second = touched cells per second: ns per cell = 1e9 / items_per_second.
  state.SetItemsProcessed(static_cast<std::int64_t>(touched) * state.iterations());
}
BENCHMARK(BM_StepUpdate)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
