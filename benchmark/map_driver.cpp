// Fixed work for profiling and memory figures of issue 6 (not a Google Benchmark: callgrind
// and /usr/bin/time need a run whose work is known in advance). Results in BENCHMARKS.md.
//
//   map_driver traverse N    N bare traversals of the 30 m scan (core_benchmark's scan)
//   map_driver integrate N   N integrations of that scan into a fixed 4000 x 4000 map, one
//                            step (after one warm-up scan)
//   map_driver scanstep N    N x (integrate + step with online EM) in that map, consecutive
//                            steps (after one warm-up scan and step)
//   map_driver octomap N     N insertions of the same scan into OctoMap (if built with it)
//   map_driver memory        the bytes per cell of a tile, then three explorations with a
//                            growing map: a 200 m x 200 m area, an L-shaped corridor and a
//                            diagonal corridor; allocated tiles against their bounding box,
//                            observed cells, and peak RSS (VmHWM) after each
//
// Per-scan instruction counts: run `valgrind --tool=callgrind` on N = 1 and N = 11 and
// divide the difference of the totals by 10 (setup and warm-up cancel out).

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/grid/traversal.h"

#include "scan_fixtures.h"

#ifdef DOG_BENCHMARK_OCTOMAP
#include <octomap/OcTree.h>
#endif

namespace dog = dynamic_occupancy_grid::core;

namespace {

using dog_benchmark::benchmarkScan;
using dog_benchmark::kResolution;
using dog_benchmark::makeScan;

long peakRssKiB() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return std::strtol(line.c_str() + 6, nullptr, 10);
  }
  return -1;
}

long rssKiB() {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::strtol(line.c_str() + 6, nullptr, 10);
  }
  return -1;
}

std::int64_t observedCells(const dog::CellGrid& grid) {
  std::int64_t observed = 0;
  grid.forEachTile([&observed](const dog::CellGrid::Tile& tile) {
    for (const std::int32_t last : tile.last_step) observed += last != dog::kNeverObserved ? 1 : 0;
  });
  return observed;
}

void report(const char* name, const dog::Mapper& mapper) {
  const dog::CellGrid& grid = mapper.grid();
  const dog::CellBox box = grid.bounds();
  const double box_cells = static_cast<double>(box.width()) * static_cast<double>(box.height());
  const double tile_cells = static_cast<double>(grid.allocatedTiles()) * dog::CellGrid::kTileCells;
  std::printf(
      "%s: bounding box %lld x %lld cells (%.1f m x %.1f m), allocated tiles %zu (%.0f cells, %.1f %% of the box), "
      "observed cells %lld, tile memory %.1f MB, RSS now %.1f MB, peak RSS %.1f MB (MB = 1e6 bytes)\n",
      name, static_cast<long long>(box.width()), static_cast<long long>(box.height()), box.width() * kResolution,
      box.height() * kResolution, grid.allocatedTiles(), tile_cells, 100.0 * tile_cells / box_cells,
      static_cast<long long>(observedCells(grid)), grid.allocatedTiles() * sizeof(dog::CellGrid::Tile) / 1e6,
      rssKiB() * 1.024e-3, peakRssKiB() * 1.024e-3);
}

// A 360-degree scan of `range_m` every `spacing_m` along the polyline through `points`
// (x0, y0, x1, y1, ...), one scan per time step.
void explorePath(dog::Mapper* mapper, const std::vector<double>& points, double spacing_m, double range_m,
                 double* stamp) {
  for (std::size_t k = 0; k + 3 < points.size(); k += 2) {
    const double x0 = points[k], y0 = points[k + 1], x1 = points[k + 2], y1 = points[k + 3];
    const double length = std::hypot(x1 - x0, y1 - y0);
    const int n = static_cast<int>(std::ceil(length / spacing_m));
    for (int i = 0; i <= n; ++i) {
      const double t = n == 0 ? 0.0 : static_cast<double>(i) / n;
      mapper->integrate(makeScan(*stamp, dog::Pose2D{x0 + t * (x1 - x0), y0 + t * (y1 - y0), 0.0}, 1440,
                                 2.0 * M_PI * 1439.0 / 1440.0, range_m));
      *stamp += 1.0;
    }
  }
  mapper->finishStep();
}

int memory() {
  std::printf("sizeof(CellGrid::Tile) = %zu bytes for %d cells: %.3f bytes per cell\n", sizeof(dog::CellGrid::Tile),
              dog::CellGrid::kTileCells, dog::CellGrid::bytesPerCell());
  std::printf("peak RSS before any map: %.1f MB\n", peakRssKiB() * 1.024e-3);
  double stamp = 0.0;
  {
    // L-shaped corridor: 100 m along x, then 100 m along y; a 3 m sensor every 1 m.
    dog::Mapper mapper(dog::MapperConfig{});
    explorePath(&mapper, {0.0, 0.0, 100.0, 0.0, 100.0, 100.0}, 1.0, 3.0, &stamp);
    report("L corridor (3 m sensor, 2 x 100 m)", mapper);
  }
  {
    // Diagonal corridor: 141 m from (0, 0) to (100, 100).
    dog::Mapper mapper(dog::MapperConfig{});
    explorePath(&mapper, {0.0, 0.0, 100.0, 100.0}, 1.0, 3.0, &stamp);
    report("diagonal corridor (3 m sensor, 141 m)", mapper);
  }
  {
    // 200 m x 200 m explored: a lawnmower over [-90, 90]^2, 360-degree scans of 15 m every
    // 5 m along lanes 20 m apart (circles of 15 m around points at most 10 m apart cover
    // the square [-100, 100]^2 up to the beam gaps at the far end).
    dog::Mapper mapper(dog::MapperConfig{});
    std::vector<double> lanes;
    for (int lane = 0; lane < 10; ++lane) {
      const double y = -90.0 + 20.0 * lane;
      const double from = lane % 2 == 0 ? -90.0 : 90.0;
      lanes.insert(lanes.end(), {from, y, -from, y});
    }
    explorePath(&mapper, lanes, 5.0, 15.0, &stamp);
    report("200 m x 200 m explored (15 m sensor)", mapper);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: map_driver traverse|integrate|scanstep|octomap N | map_driver memory\n");
    return 2;
  }
  const std::string mode = argv[1];
  if (mode == "memory") return memory();
  const int n = argc > 2 ? std::atoi(argv[2]) : 1;
  const dog::Scan scan = benchmarkScan(0.0);
  if (mode == "traverse") {
    // As BM_ScanTraversal: every cell of every beam visited once, nothing stored.
    std::int64_t sum = 0;
    for (int k = 0; k < n; ++k) {
      dog_benchmark::traverseBeams(scan, [&sum](std::int32_t x, std::int32_t y) { sum += x ^ y; });
    }
    std::printf("%lld\n", static_cast<long long>(sum));
    return 0;
  }
  if (mode == "integrate" || mode == "scanstep") {
    dog::Mapper mapper(dog_benchmark::fixedMapConfig(4000));
    mapper.integrate(scan);
    if (mode == "scanstep") mapper.finishStep();
    dog::Scan next = scan;
    std::size_t beams = 0;
    for (int k = 0; k < n; ++k) {
      if (mode == "scanstep") next.stamp_s += 1.0;
      beams += mapper.integrate(next).beams_hit;
      if (mode == "scanstep") mapper.finishStep();
    }
    std::printf("%zu beams, %zu tiles\n", beams, mapper.grid().allocatedTiles());
    return 0;
  }
#ifdef DOG_BENCHMARK_OCTOMAP
  if (mode == "octomap") {
    const octomap::point3d origin(static_cast<float>(scan.laser_pose.x_m), static_cast<float>(scan.laser_pose.y_m),
                                  0.0f);
    const octomap::Pointcloud cloud = dog_benchmark::octomapCloud(scan);
    octomap::OcTree tree(kResolution);
    tree.insertPointCloud(cloud, origin, scan.range_max_m);
    for (int k = 0; k < n; ++k) tree.insertPointCloud(cloud, origin, scan.range_max_m);
    std::printf("%zu nodes\n", tree.size());
    return 0;
  }
#endif
  std::fprintf(stderr, "map_driver: unknown mode %s\n", mode.c_str());
  return 2;
}
