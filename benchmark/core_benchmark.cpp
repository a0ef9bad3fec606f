// Google Benchmark for the core's hot paths. Results and the command are in BENCHMARKS.md.
//   One scan: 1081 beams over 270 degrees, every beam a hit at 29.97 m (the worst case of a
//   30 m sensor), 0.05 m cells.
//   Learning: online EM per observed cell-step; offline EM in observed cell-steps per
//   second per iteration.
//   Issue 6: the same scan into a fixed 4000 x 4000 map (200 m x 200 m, sensor in the
//   middle), scan + step as one figure, the per-scan cost against the map's size, and (when
//   CMake found OctoMap) OctoMap inserting the same scan as a point cloud.
//   Issue 18: the textbook log-odds occupancy grid update of the same scan
//   (BM_TextbookLogOddsScan), the price of the HMM as a ratio to what gmapping or
//   costmap_2d pay per cell.
//   Issue 19: one update of the pose filter (30 particles, a 720-beam 30 m laser, 0.5 m
//   apart) in a 50 m x 50 m hall the robot has explored, and the particles' map memory
//   against one map's.

#include <benchmark/benchmark.h>

#include <cmath>
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <random>
#include <utility>
#include <vector>

#include "dynamic_occupancy_grid/core/cell/cell_model.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/cell/offline_em.h"
#include "dynamic_occupancy_grid/core/cell/online_em.h"
#include "dynamic_occupancy_grid/core/pose/corrected_mapping.h"
#include "dynamic_occupancy_grid/core/pose/pose_filter.h"
#include "dynamic_occupancy_grid/core/grid/traversal.h"

#include "scan_fixtures.h"

#ifdef DOG_BENCHMARK_OCTOMAP
#include <octomap/OcTree.h>
#endif

namespace dog = dynamic_occupancy_grid::core;

namespace {

using dog_benchmark::fixedMapConfig;
using dog_benchmark::kBeams;
using dog_benchmark::kResolution;

dog::Scan makeScan(double stamp_s, double range_m = dog_benchmark::kRange) {
  return dog_benchmark::benchmarkScan(stamp_s, range_m);
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
    dog_benchmark::traverseBeams(scan, [&sum, &visits](std::int32_t x, std::int32_t y) {
      sum += x ^ y;
      ++visits;
    });
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

// Issue 6: the same as BM_ScanIntegrate, in a fixed map of arg x arg cells (4000: 200 m x
// 200 m) with the sensor in its middle, instead of a growing map.
void BM_ScanIntegrateFixedMap(benchmark::State& state) {
  dog::Mapper mapper(fixedMapConfig(state.range(0)));
  const dog::Scan scan = makeScan(0.0);
  mapper.integrate(scan);
  std::size_t beams = 0;
  for (auto _ : state) {
    const dog::ScanResult result = mapper.integrate(scan);
    beams += result.beams_hit;
  }
  benchmark::DoNotOptimize(beams);
  state.SetLabel("fixed " + std::to_string(state.range(0)) + "^2 map, area allocated, step stays open");
}
BENCHMARK(BM_ScanIntegrateFixedMap)->Arg(4000)->Unit(benchmark::kMicrosecond);

// Issue 6: what one scan costs when every scan is its own time step (the worst case: no
// step update is shared by several scans): integrate into the 4000 x 4000 map, then apply
// the step to the ~623 k cells touched (filter + online EM + baseline, consecutive steps).
// This is the figure compared with OctoMap's insertion of the same scan.
void BM_ScanAndStep(benchmark::State& state) {
  dog::MapperConfig config = fixedMapConfig(4000);
  config.learn_transitions = state.range(0) != 0;
  dog::Mapper mapper(config);
  double stamp = 0.0;
  mapper.integrate(makeScan(stamp));
  mapper.finishStep();
  dog::Scan scan = makeScan(stamp);
  for (auto _ : state) {
    stamp += 1.0;  // the next step: no unobserved gap
    scan.stamp_s = stamp;
    mapper.integrate(scan);
    mapper.finishStep();
    benchmark::DoNotOptimize(mapper.takeChangedCells());
  }
  state.SetItemsProcessed(state.iterations() * kBeams);  // beams per second
  state.SetLabel(config.learn_transitions ? "4000^2 map, integrate + filter + online EM"
                                          : "4000^2 map, integrate + filter only");
}
BENCHMARK(BM_ScanAndStep)->Arg(1)->Arg(0)->Unit(benchmark::kMicrosecond);

// Issue 6: per-scan cost against the map's size. The same 12 m scan (fits in the smallest
// map: 500 cells = 25 m, sensor in the middle) into fixed maps of arg x arg cells,
// integrate + step (online EM) per scan. The cost should not depend on the map's size.
void BM_ScanMapSize(benchmark::State& state) {
  dog::Mapper mapper(fixedMapConfig(state.range(0)));
  double stamp = 0.0;
  dog::Scan scan = makeScan(stamp, 12.0);
  mapper.integrate(scan);
  mapper.finishStep();
  std::size_t outside = 0;
  for (auto _ : state) {
    stamp += 1.0;
    scan.stamp_s = stamp;
    outside += mapper.integrate(scan).cells_outside;
    mapper.finishStep();
    benchmark::DoNotOptimize(mapper.takeChangedCells());
  }
  state.counters["cells_outside"] = static_cast<double>(outside);  // 0: the scan fits
  state.counters["tiles"] = static_cast<double>(mapper.grid().allocatedTiles());
  state.SetItemsProcessed(state.iterations() * kBeams);
  state.SetLabel("12 m scan, integrate + step, " + std::to_string(state.range(0)) + "^2 map");
}
BENCHMARK(BM_ScanMapSize)->Arg(500)->Arg(8000)->Unit(benchmark::kMicrosecond);

// Issue 18's second peer: the textbook occupancy grid update of the same scan, what gmapping
// or costmap_2d pay per cell. A dense 4000 x 4000 grid (200 m x 200 m, sensor in the middle
// as for BM_ScanAndStep) of log-odds, each beam traced by Bresenham's line from the sensor's
// cell to its end cell; every cell before the end gets the miss log-odds added, the end cell
// the hit's, each clamped to the static baseline's [-2, 3.5] at once. The sensor model is the
// mapper's (hit +1.25, miss -0.98). No time steps, no per-scan de-duplication (a cell crossed
// by two beams is updated twice), no learning. Argument 0: float log-odds (64 MB grid);
// 1: int8 log-odds in steps of 1/32 (16 MB grid, costmap_2d's byte per cell).
template <class T>
struct TextbookGrid {
  static constexpr std::int32_t kSide = 4000;
  std::vector<T> cells = std::vector<T>(static_cast<std::size_t>(kSide) * kSide, T{});
  T hit;
  T miss;
  T min;
  T max;

  void update(std::int32_t x, std::int32_t y, T delta) {
    if (x < 0 || y < 0 || x >= kSide || y >= kSide) return;
    T& cell = cells[(static_cast<std::size_t>(y) * kSide) + x];
    cell = std::clamp<T>(static_cast<T>(cell + delta), min, max);
  }

  // Bresenham from (x0, y0) to (x1, y1): misses before the end, a hit at the end.
  void beam(std::int32_t x0, std::int32_t y0, std::int32_t x1, std::int32_t y1) {
    const std::int32_t dx = std::abs(x1 - x0);
    const std::int32_t dy = -std::abs(y1 - y0);
    const std::int32_t sx = x0 < x1 ? 1 : -1;
    const std::int32_t sy = y0 < y1 ? 1 : -1;
    std::int32_t error = dx + dy;
    while (x0 != x1 || y0 != y1) {
      update(x0, y0, miss);
      const std::int32_t e2 = 2 * error;
      if (e2 >= dy) {
        error += dy;
        x0 += sx;
      }
      if (e2 <= dx) {
        error += dx;
        y0 += sy;
      }
    }
    update(x1, y1, hit);
  }
};

template <class T>
void textbookScan(benchmark::State& state, double quantum) {
  const dog::Scan scan = makeScan(0.0);
  const dog::MapperConfig config = fixedMapConfig(TextbookGrid<T>::kSide);
  const dog::ObservationModel sensor(config.p_hit_given_occ, config.p_hit_given_free);
  TextbookGrid<T> grid;
  // In units of `quantum` (1 for floats: the log-odds themselves).
  const auto in_units = [quantum](double log_odds) {
    return static_cast<T>(quantum == 1.0 ? log_odds : static_cast<double>(std::lround(log_odds / quantum)));
  };
  grid.hit = in_units(sensor.hitLogOdds());
  grid.miss = in_units(sensor.missLogOdds());
  grid.min = in_units(config.static_clamp.min_log_odds);
  grid.max = in_units(config.static_clamp.max_log_odds);
  // Grid coordinates: cell (0, 0) at the map's lower-left corner, as the mapper's fixed map.
  const double u0 = (scan.laser_pose.x_m - config.origin_x_m) / kResolution;
  const double v0 = (scan.laser_pose.y_m - config.origin_y_m) / kResolution;
  std::vector<std::pair<std::int32_t, std::int32_t>> ends;
  for (int i = 0; i < kBeams; ++i) {
    const double angle = scan.laser_pose.yaw_rad + scan.angle_min_rad + i * scan.angle_increment_rad;
    const double range = scan.ranges_m[static_cast<std::size_t>(i)];
    ends.emplace_back(static_cast<std::int32_t>(std::floor(u0 + std::cos(angle) * range / kResolution)),
                      static_cast<std::int32_t>(std::floor(v0 + std::sin(angle) * range / kResolution)));
  }
  const auto x0 = static_cast<std::int32_t>(std::floor(u0));
  const auto y0 = static_cast<std::int32_t>(std::floor(v0));
  for (const auto& [x1, y1] : ends) grid.beam(x0, y0, x1, y1);  // the area is "allocated"
  for (auto _ : state) {
    for (const auto& [x1, y1] : ends) grid.beam(x0, y0, x1, y1);
    benchmark::ClobberMemory();
  }
  benchmark::DoNotOptimize(grid.cells.data());
  double updates = 0.0;  // Bresenham visits max(|dx|, |dy|) + 1 cells per beam
  for (const auto& [x1, y1] : ends) updates += std::max(std::abs(x1 - x0), std::abs(y1 - y0)) + 1;
  state.counters["cell_updates"] = updates;
  state.SetItemsProcessed(state.iterations() * kBeams);  // beams per second
}

void BM_TextbookLogOddsScan(benchmark::State& state) {
  if (state.range(0) == 0) {
    textbookScan<float>(state, 1.0);
    state.SetLabel("dense 4000^2 float log-odds, Bresenham, add + clamp");
  } else {
    textbookScan<std::int8_t>(state, 1.0 / 32.0);
    state.SetLabel("dense 4000^2 int8 log-odds (1/32), Bresenham, add + clamp");
  }
}
BENCHMARK(BM_TextbookLogOddsScan)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);

#ifdef DOG_BENCHMARK_OCTOMAP
// Issue 6's peer: OctoMap (Debian liboctomap-dev) inserting the same scan as a point cloud
// at z = 0: OcTree(0.05), insertPointCloud(cloud, origin, 30 m) with its defaults (exact
// ray casting, no lazy evaluation: inner nodes updated per scan). The tree already holds
// the area (one scan inserted before timing), as for BM_ScanIntegrate.
void BM_OctoMapInsertScan(benchmark::State& state) {
  const dog::Scan scan = makeScan(0.0);
  const octomap::point3d origin(static_cast<float>(scan.laser_pose.x_m), static_cast<float>(scan.laser_pose.y_m),
                                0.0f);
  const octomap::Pointcloud cloud = dog_benchmark::octomapCloud(scan);
  octomap::OcTree tree(kResolution);
  tree.insertPointCloud(cloud, origin, scan.range_max_m);
  for (auto _ : state) {
    tree.insertPointCloud(cloud, origin, scan.range_max_m);
  }
  benchmark::DoNotOptimize(tree.size());
  state.counters["nodes"] = static_cast<double>(tree.size());
  state.SetItemsProcessed(state.iterations() * kBeams);  // beams per second
  state.SetLabel("OcTree(0.05), insertPointCloud, maxrange 30 m");
}
BENCHMARK(BM_OctoMapInsertScan)->Unit(benchmark::kMicrosecond);
#endif

// Applying a step: every cell touched by one scan is brought over its gap, filtered (and,
// with argument 1, its online EM statistics updated) and its baseline updated. Reported per
// touched cell.
void BM_StepUpdate(benchmark::State& state) {
  dog::MapperConfig config = benchmarkConfig();
  config.learn_transitions = state.range(0) != 0;
  if (state.range(0) == 2) config.learner = dog::TransitionLearner::kCellEm;
  dog::Mapper mapper(config);
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
  state.SetLabel(!config.learn_transitions ? "filter only"
                 : config.learner == dog::TransitionLearner::kKinds ? "kinds of cells (the default)"
                                                                       : "each cell's online EM");
}
// 0: learning off; 1: the default learner (kinds of cells); 2: each cell's online EM.
BENCHMARK(BM_StepUpdate)->Arg(0)->Arg(1)->Arg(2)->Unit(benchmark::kMicrosecond);

// The online EM kernel alone (onlineLearnStep in double, no grid): argument = the gap of
// unobserved steps before each observed step (0: seen every step; 5: the closed-form skip).
void BM_OnlineLearnStep(benchmark::State& state) {
  const std::int64_t gap = state.range(0);
  const dog::OnlineEmConfig config;
  const dog::TransitionParams prior{0.01, 0.01};
  constexpr int kCells = 4096;
  std::vector<dog::OnlineCell> cells(kCells, dog::newOnlineCell(prior, 0.5, config));
  std::mt19937_64 rng(7);
  std::vector<double> evidence(kCells);
  for (double& e : evidence) e = (rng() % 2 == 0) ? 1.25 : -0.98;
  for (auto _ : state) {
    for (int i = 0; i < kCells; ++i) dog::onlineLearnStep(cells[i], gap, evidence[i], prior, config);
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * kCells);  // observed cell-steps per second
}
BENCHMARK(BM_OnlineLearnStep)->Arg(0)->Arg(5);

// Offline EM on synthetic data: 4096 cells x 200 observed steps, gaps of 1 to 4 steps, one
// or two beams per observation; 10 iterations per cell (tolerance 0). Argument = threads.
// items_per_second = observed cell-steps per second per iteration.
void BM_OfflineEm(benchmark::State& state) {
  constexpr int kCells = 4096;
  constexpr int kObservations = 200;
  constexpr int kIterations = 10;
  std::mt19937_64 rng(11);
  dog::SequenceBuilder builder;
  for (int cell = 0; cell < kCells; ++cell) {
    bool occupied = false;
    std::int32_t step = 0;
    for (int k = 0; k < kObservations; ++k) {
      step += 1 + static_cast<std::int32_t>(rng() % 4);
      if (rng() % 10 == 0) occupied = !occupied;
      const std::uint32_t beams = 1 + static_cast<std::uint32_t>(rng() % 2);
      builder.add(cell, 0, step, occupied ? beams : 0, occupied ? 0 : beams);
    }
  }
  const dog::ObservationSequences sequences = builder.build();
  const dog::ObservationModel sensor(0.7, 0.2);
  dog::OfflineEmConfig config;
  config.tolerance = 0.0;
  config.max_iterations = kIterations;
  config.threads = static_cast<unsigned>(state.range(0));
  for (auto _ : state) {
    const dog::OfflineEmResult result = dog::runOfflineEm(sequences, sensor, config);
    benchmark::DoNotOptimize(result.objective.back());
  }
  state.SetItemsProcessed(state.iterations() * static_cast<std::int64_t>(sequences.observationCount()) *
                          (kIterations + 1));  // + 1: the E-step of the initial parameters
  state.SetLabel("threads " + std::to_string(state.range(0)));
}
BENCHMARK(BM_OfflineEm)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

// --- issue 19: the pose filter -----------------------------------------------------------

// A 50 m x 50 m hall with 0.6 m pillars every 6 m; rays cast exactly.
struct Hall {
  struct Box {
    double min_x, min_y, max_x, max_y;
  };
  std::vector<Box> boxes;
  Hall() {
    boxes = {{-0.3, -0.3, 50.3, 0.0}, {-0.3, 50.0, 50.3, 50.3}, {-0.3, 0.0, 0.0, 50.0}, {50.0, 0.0, 50.3, 50.0}};
    for (double x = 4.0; x < 48.0; x += 6.0) {
      for (double y = 4.0; y < 48.0; y += 6.0) boxes.push_back({x, y, x + 0.6, y + 0.6});
    }
  }
  double cast(double x, double y, double angle) const {
    const double dx = std::cos(angle);
    const double dy = std::sin(angle);
    double nearest = 1e9;
    for (const Box& b : boxes) {
      for (const double side : {b.min_x, b.max_x}) {
        const double t = std::abs(dx) < 1e-12 ? -1.0 : (side - x) / dx;
        const double hit = y + t * dy;
        if (t > 1e-9 && hit >= b.min_y && hit <= b.max_y) nearest = std::min(nearest, t);
      }
      for (const double side : {b.min_y, b.max_y}) {
        const double t = std::abs(dy) < 1e-12 ? -1.0 : (side - y) / dy;
        const double hit = x + t * dx;
        if (t > 1e-9 && hit >= b.min_x && hit <= b.max_x) nearest = std::min(nearest, t);
      }
    }
    return nearest;
  }
  dog::Scan scan(const dog::Pose2D& pose, double stamp_s) const {
    dog::Scan scan = dog_benchmark::makeScan(stamp_s, pose, 720, 1.5 * M_PI, 0.0);
    for (int i = 0; i < 720; ++i) {
      const double range = cast(pose.x_m, pose.y_m, pose.yaw_rad + scan.angle_min_rad + i * scan.angle_increment_rad);
      scan.ranges_m[i] = static_cast<float>(range < 30.0 ? range : INFINITY);
    }
    return scan;
  }
};

// The robot's laser along a 40 m x 40 m square loop inside the hall, `step` metres apart.
dog::Pose2D loopPose(double distance_m) {
  const double side = 40.0;
  const double s = std::fmod(distance_m, 4.0 * side);
  const int leg = static_cast<int>(s / side);
  const double along = s - leg * side;
  switch (leg) {
    case 0: return {5.0 + along, 5.0, 0.0};
    case 1: return {45.0, 5.0 + along, M_PI / 2};
    case 2: return {45.0 - along, 45.0, M_PI};
    default: return {5.0, 45.0 - along, -M_PI / 2};
  }
}

// One update per iteration (the odometry moved 0.5 m since the last), after a whole loop
// that explored the hall; argument = particles. Counters: the particles' map memory (each
// distinct tile once) over one particle's map, and MB.
void BM_PoseFilterUpdate(benchmark::State& state) {
  const Hall hall;
  dog::PoseFilterConfig config;
  config.particles = static_cast<std::size_t>(state.range(0));
  config.resolution_m = kResolution;
  config.max_range_m = 30.0;
  config.max_free_range_m = 29.0;
  config.update_distance_m = 0.5;
  config.motion_noise = {0.01, 0.001, 0.005, 0.002};
  dog::PoseFilter filter(config, std::make_shared<dog::UniformTransitions>(dog::TransitionParams{0.0, 0.0}));
  double travelled = 0.0;
  double stamp = 0.0;
  for (; travelled < 160.0; travelled += 0.5, stamp += 0.5) filter.integrate(hall.scan(loopPose(travelled), stamp));
  double peak_bytes = 0.0;
  for (auto _ : state) {
    state.PauseTiming();
    const dog::Scan scan = hall.scan(loopPose(travelled), stamp);
    travelled += 0.5;
    stamp += 0.5;
    state.ResumeTiming();
    const dog::PoseUpdate update = filter.integrate(scan);
    peak_bytes = std::max(peak_bytes, static_cast<double>(update.map_bytes));
  }
  // One map: the best particle's, all of its tiles.
  const double one = static_cast<double>(dog::ParticleMap::distinctTileBytes({&filter.best().map}));
  state.counters["peak_memory_vs_one_map"] = peak_bytes / one;
  state.counters["one_map_MB"] = one / 1e6;
  state.SetLabel(std::to_string(config.particles) + " particles, 720 beams, 30 m, 0.05 m cells, 50 m hall explored");
}
BENCHMARK(BM_PoseFilterUpdate)->Arg(30)->Unit(benchmark::kMillisecond)->UseRealTime();

// The node's path with pose correction: one scan through CorrectedMapping (the filter, its
// test of the correction against the settled map, the Mapper) per iteration, the laser
// 0.5 m and 0.5 s further along the loop, after a whole loop. Every 60th scan (30 s) also
// takes a snapshot of the Mapper's map (the settled map's next). Counter: the slowest
// scan, ms.
void BM_CorrectedMappingScan(benchmark::State& state) {
  const Hall hall;
  dog::MapperConfig mapper_config;
  mapper_config.resolution_m = kResolution;
  mapper_config.max_free_range_m = 29.0;
  dog::Mapper mapper(mapper_config);
  dog::PoseFilterConfig config;
  config.particles = static_cast<std::size_t>(state.range(0));
  config.max_range_m = 30.0;
  config.update_distance_m = 0.5;
  config.motion_noise = {0.01, 0.001, 0.005, 0.002};
  dog::CorrectedMapping mapping(mapper, dog::poseFilterConfigFor(mapper_config, config), 30);
  double travelled = 0.0;
  double stamp = 0.0;
  for (; travelled < 160.0; travelled += 0.5, stamp += 0.5) mapping.integrate(hall.scan(loopPose(travelled), stamp));
  double slowest_ms = 0.0;
  for (auto _ : state) {
    state.PauseTiming();
    const dog::Scan scan = hall.scan(loopPose(travelled), stamp);
    travelled += 0.5;
    stamp += 0.5;
    state.ResumeTiming();
    const auto start = std::chrono::steady_clock::now();
    benchmark::DoNotOptimize(mapping.integrate(scan));
    slowest_ms = std::max(slowest_ms,
                          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
  }
  state.counters["slowest_scan_ms"] = slowest_ms;
  state.SetLabel(std::to_string(config.particles) + " particles, 720 beams, 30 m, 0.05 m cells, 50 m hall explored");
}
BENCHMARK(BM_CorrectedMappingScan)->Arg(30)->Iterations(120)->Unit(benchmark::kMillisecond)->UseRealTime();

// What a taken correction costs the node (CorrectedMapping maps the scans since the settled
// checkpoint again, core/pose/corrected_mapping.h): a copy of the Mapper as it was at the
// checkpoint, after a whole loop of the hall, then the next 60 s of scans (0.5 m/s) mapped
// into it, per iteration; argument = scans in those 60 s (120: 2 Hz, 600: a 10 Hz laser).
// Counters: the copy alone (what a checkpoint every 30 s costs), ms; the map, MB.
void BM_RemapAfterCorrection(benchmark::State& state) {
  const Hall hall;
  dog::MapperConfig mapper_config;
  mapper_config.resolution_m = kResolution;
  mapper_config.max_free_range_m = 29.0;
  dog::Mapper mapper(mapper_config);
  double travelled = 0.0;
  double stamp = 0.0;
  for (; travelled < 160.0; travelled += 0.5, stamp += 0.5) mapper.integrate(hall.scan(loopPose(travelled), stamp));
  const auto scans = static_cast<std::size_t>(state.range(0));
  std::vector<dog::Scan> since;
  for (std::size_t i = 0; i < scans; ++i) {
    const double share = static_cast<double>(i) / static_cast<double>(scans);
    since.push_back(hall.scan(loopPose(travelled + 30.0 * share), stamp + 60.0 * share));
  }
  const dog::Mapper checkpoint(mapper);
  double copy_ms = 0.0;
  for (auto _ : state) {
    const auto start = std::chrono::steady_clock::now();
    dog::Mapper rebuilt(checkpoint);
    copy_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    for (const dog::Scan& scan : since) rebuilt.integrate(scan);
    benchmark::DoNotOptimize(rebuilt.lastAppliedStep());
  }
  state.counters["copy_ms"] = copy_ms / static_cast<double>(state.iterations());
  state.counters["map_MB"] =
      static_cast<double>(checkpoint.grid().allocatedTiles()) * sizeof(dog::CellGrid::Tile) / 1e6;
  state.SetLabel(std::to_string(scans) + " scans, 720 beams, 30 m, 0.05 m cells, 50 m hall explored");
}
BENCHMARK(BM_RemapAfterCorrection)->Arg(120)->Arg(600)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
