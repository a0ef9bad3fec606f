#include "dynamic_occupancy_grid/core/grid/scan_beams.h"

#include <algorithm>
#include <cmath>
#include <cstdint>

namespace dynamic_occupancy_grid {
namespace core {
namespace {

// The heading of beam i in the map frame (Scan's definition).
double beamHeading(const Scan& scan, std::size_t i) {
  const double beam_angle = scan.angle_min_rad + static_cast<double>(i) * scan.angle_increment_rad;
  return scan.laser_pose.yaw_rad + (scan.upside_down ? -beam_angle : beam_angle);
}

}  // namespace

std::optional<std::string> scanFieldsError(const Scan& scan) {
  if (scan.ranges_m.empty()) return std::string("empty scan (no ranges)");
  if (!std::isfinite(scan.stamp_s)) return std::string("stamp is not finite");
  const Pose2D& pose = scan.laser_pose;
  if (!std::isfinite(pose.x_m) || !std::isfinite(pose.y_m) || !std::isfinite(pose.yaw_rad)) {
    return std::string("laser pose is not finite");
  }
  if (!std::isfinite(scan.angle_min_rad) || !std::isfinite(scan.angle_increment_rad) ||
      (scan.ranges_m.size() > 1 && scan.angle_increment_rad == 0.0)) {
    return std::string("angle_min and angle_increment must be finite, and angle_increment non-zero");
  }
  // Finite angles can still add up to an infinite heading (angle_increment 1e308 over a few
  // beams, a yaw near the largest double), whose cosine is NaN. The headings are monotonic
  // in the beam index, so the first and the last beam bound them all.
  if (!std::isfinite(beamHeading(scan, 0)) || !std::isfinite(beamHeading(scan, scan.ranges_m.size() - 1))) {
    return std::string("beam headings are not finite (laser yaw + angle_min + i * angle_increment overflows)");
  }
  if (!(scan.range_min_m >= 0.0) || !std::isfinite(scan.range_min_m) || !(scan.range_max_m > scan.range_min_m)) {
    return "need 0 <= range_min < range_max, got range_min " + std::to_string(scan.range_min_m) + ", range_max " +
           std::to_string(scan.range_max_m);
  }
  return std::nullopt;
}

std::optional<std::size_t> beamEnds(const Scan& scan, double u0, double v0, const BeamRules& rules,
                                    std::vector<BeamEnd>& ends, BeamCounts& counts, CellBox& box) {
  ends.clear();
  ends.reserve(scan.ranges_m.size());
  // A beam without return says nothing is nearer than range_max, but a surface just inside
  // range_max reads beyond it about as often as not (range noise): stop one cell short, or
  // the cell of a wall at the laser's limit collects misses and looks like a cell that
  // changes.
  const double free_range_m = std::min(rules.max_free_range_m, scan.range_max_m - 1.0 / rules.cells_per_m);
  box.include(static_cast<std::int32_t>(std::floor(u0)), static_cast<std::int32_t>(std::floor(v0)));
  for (std::size_t i = 0; i < scan.ranges_m.size(); ++i) {
    const double range = scan.ranges_m[i];
    double length_m;
    bool hit;
    if (std::isnan(range) || range < scan.range_min_m) {
      ++counts.ignored;
      continue;
    }
    if (range >= scan.range_max_m) {  // includes +inf
      ++counts.no_return;
      if (free_range_m <= 0.0) continue;
      length_m = free_range_m;
      hit = false;
    } else {
      ++counts.hit;
      length_m = range;
      hit = true;
    }
    // No beam needs to be longer than the map's diagonal: its cells beyond that are
    // outside the map anyway, and walking them would cost time for nothing.
    if (length_m > rules.max_beam_m) {
      length_m = rules.max_beam_m;
      hit = false;
    }
    const double angle = beamHeading(scan, i);
    const double u1 = u0 + std::cos(angle) * length_m * rules.cells_per_m;
    const double v1 = v0 + std::sin(angle) * length_m * rules.cells_per_m;
    if (std::abs(u1) > kMaxLatticeCoordinate || std::abs(v1) > kMaxLatticeCoordinate) return i;
    box.include(static_cast<std::int32_t>(std::floor(u1)), static_cast<std::int32_t>(std::floor(v1)));
    ends.push_back(BeamEnd{u1, v1, hit});
  }
  return std::nullopt;
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
