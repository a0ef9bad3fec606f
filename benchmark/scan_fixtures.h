#pragma once
// The scan and maps the benchmarks share (core_benchmark, map_driver): the worst case of a
// 30 m laser, 1081 beams over 270 degrees, every beam a hit at 29.97 m, 0.05 m cells.

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/grid/traversal.h"

#ifdef DOG_BENCHMARK_OCTOMAP
#include <octomap/octomap.h>
#endif

namespace dog_benchmark {

namespace dog = dynamic_occupancy_grid::core;

constexpr int kBeams = 1081;
constexpr double kFieldOfView = 1.5 * M_PI;
constexpr double kRange = 29.97;
constexpr double kResolution = 0.05;

inline dog::Scan makeScan(double stamp_s, const dog::Pose2D& pose, int beams, double field_of_view,
                          double range_m) {
  dog::Scan scan;
  scan.stamp_s = stamp_s;
  scan.laser_pose = pose;
  scan.angle_min_rad = -field_of_view / 2.0;
  scan.angle_increment_rad = field_of_view / (beams - 1);
  scan.range_min_m = 0.1;
  scan.range_max_m = 30.0;
  scan.ranges_m.assign(beams, static_cast<float>(range_m));
  return scan;
}

/// The benchmark scan (every beam reading `range_m`) from a pose near the origin.
inline dog::Scan benchmarkScan(double stamp_s, double range_m = kRange) {
  return makeScan(stamp_s, dog::Pose2D{0.013, -0.021, 0.1}, kBeams, kFieldOfView, range_m);
}

/// A fixed map of side x side cells centred on the world origin (the scan's sensor is at
/// the origin, so it sits in the middle of the map).
inline dog::MapperConfig fixedMapConfig(std::int64_t side_cells) {
  dog::MapperConfig config;
  config.resolution_m = kResolution;
  config.fixed_bounds = true;
  config.width_m = static_cast<double>(side_cells) * kResolution;
  config.height_m = config.width_m;
  config.origin_x_m = -config.width_m / 2.0;
  config.origin_y_m = -config.height_m / 2.0;
  config.max_map_size_m = std::max(config.max_map_size_m, config.width_m);
  return config;
}

/// The bare traversal of the benchmark scan's beams: visit(x, y) for every cell of every
/// beam (its end cell included), nothing stored. The floor any scan insertion pays.
template <class Visit>
void traverseBeams(const dog::Scan& scan, Visit&& visit) {
  const double u0 = scan.laser_pose.x_m / kResolution;
  const double v0 = scan.laser_pose.y_m / kResolution;
  for (int i = 0; i < kBeams; ++i) {
    const double angle = scan.laser_pose.yaw_rad + scan.angle_min_rad + i * scan.angle_increment_rad;
    const dog::CellXY end = dog::traverseSegment(
        u0, v0, u0 + std::cos(angle) * kRange / kResolution, v0 + std::sin(angle) * kRange / kResolution, visit);
    visit(end.x, end.y);
  }
}

#ifdef DOG_BENCHMARK_OCTOMAP
/// The benchmark scan's end points as OctoMap's point cloud at z = 0 (the peer's input).
inline octomap::Pointcloud octomapCloud(const dog::Scan& scan) {
  octomap::Pointcloud cloud;
  for (int i = 0; i < kBeams; ++i) {
    const double angle = scan.laser_pose.yaw_rad + scan.angle_min_rad + i * scan.angle_increment_rad;
    cloud.push_back(static_cast<float>(scan.laser_pose.x_m + std::cos(angle) * kRange),
                    static_cast<float>(scan.laser_pose.y_m + std::sin(angle) * kRange), 0.0f);
  }
  return cloud;
}
#endif

}  // namespace dog_benchmark
