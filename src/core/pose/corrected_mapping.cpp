#include "dynamic_occupancy_grid/core/pose/corrected_mapping.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "dynamic_occupancy_grid/core/layers/model_io.h"
#include "dynamic_occupancy_grid/core/pose/motion_model.h"
#include "dynamic_occupancy_grid/core/pose/particle_map.h"

namespace dynamic_occupancy_grid {
namespace core {

namespace {

constexpr double kPi = 3.14159265358979323846;
/// The longest beam the filter walks, in cells (PoseFilterConfig allows 1022).
constexpr double kMaxFilterRangeCells = 1000.0;

Pose2D wrapped(Pose2D pose) {
  pose.yaw_rad = std::remainder(pose.yaw_rad, 2.0 * kPi);
  return pose;
}

}  // namespace

PoseFilterConfig poseFilterConfigFor(const MapperConfig& mapper, PoseFilterConfig filter) {
  filter.resolution_m = mapper.resolution_m;
  filter.time_step_s = mapper.time_step_s;
  filter.p_hit_given_occ = mapper.p_hit_given_occ;
  filter.p_hit_given_free = mapper.p_hit_given_free;
  filter.max_free_range_m = mapper.max_free_range_m;
  filter.max_range_m = std::min(filter.max_range_m, kMaxFilterRangeCells * mapper.resolution_m);
  return filter;
}

CorrectedMapping::CorrectedMapping(Mapper& mapper, const PoseFilterConfig& filter,
                                   std::uint32_t learned_min_observed_steps, const Pose2D& start_correction)
    : mapper_(mapper),
      filter_(std::make_unique<PoseFilter>(
          filter, std::make_shared<MapperTransitions>(mapper, filter.resolution_m, learned_min_observed_steps))),
      start_correction_(wrapped(start_correction)) {}

CorrectedScan CorrectedMapping::integrate(const Scan& odometry_scan) {
  // The filter sees odometry moved by the start correction, so that its frame is the map
  // frame: the particles' cells are the Mapper's (MapperTransitions reads them there).
  Scan shifted = odometry_scan;
  shifted.laser_pose = wrapped(composePose(start_correction_, odometry_scan.laser_pose));
  if (!filter_->started()) {
    // The filter's steps are the Mapper's, moved by whole steps (up to rounding at a step's
    // border): step 0 starts where the Mapper's step of this scan does (at the scan on a
    // fresh Mapper).
    const StepClock& clock = mapper_.clock();
    const double stamp = odometry_scan.stamp_s;
    double origin = stamp;
    if (clock.origin() && std::isfinite(stamp) && clock.stepOf(stamp) >= 0) {
      const double start = clock.stepStart(clock.stepOf(stamp));
      if (start <= stamp && stamp - start < clock.timeStep()) origin = start;  // else rounding: the stamp
    }
    filter_->startStepsAt(origin);
  }
  CorrectedScan result;
  result.update = filter_->integrate(shifted);
  result.corrected = odometry_scan;
  result.corrected.laser_pose = wrapped(composePose(filter_->mapToOdometry(), shifted.laser_pose));
  result.mapped = mapper_.integrate(result.corrected);
  return result;
}

Pose2D CorrectedMapping::mapToOdometry() const {
  if (!filter_->started()) return start_correction_;
  return wrapped(composePose(filter_->mapToOdometry(), start_correction_));
}

ParticleBelief CorrectedMapping::bestParticleBelief(std::int64_t horizon_steps) const {
  if (horizon_steps < 0) throw std::invalid_argument("bestParticleBelief: horizon_steps must be >= 0");
  ParticleBelief belief;
  if (!filter_->started()) return belief;
  const ParticleMap& map = filter_->best().map;
  const CellBox cells = map.bounds();
  const double r = filter_->config().resolution_m;
  belief.window = MapWindow{r, cells.min_x * r, cells.min_y * r, cells};
  if (cells.empty()) return belief;
  const std::int64_t step = filter_->lastUpdateStep() + horizon_steps;
  const double unknown = filter_->config().unknown_p_occ;
  belief.values.reserve(static_cast<std::size_t>(cells.width() * cells.height()));
  ParticleMap::Reader reader(map);
  for (std::int32_t y = cells.min_y; y <= cells.max_y; ++y) {
    for (std::int32_t x = cells.min_x; x <= cells.max_x; ++x) {
      belief.values.push_back(reader.lastStep(x, y) == kNeverObserved
                                  ? std::numeric_limits<float>::quiet_NaN()
                                  : static_cast<float>(reader.predicted(x, y, step, filter_->transitions(), unknown)));
    }
  }
  return belief;
}

std::string CorrectedMapping::serializeModel(BestParticleCells* cells) const {
  BestParticleCells counts;
  std::string bytes;
  if (!filter_->started() || !mapper_.clock().origin()) {
    bytes = core::serializeModel(mapper_);
  } else {
    const ParticleMap& map = filter_->best().map;
    const CellGrid& grid = mapper_.grid();
    const StepClock& mapper_clock = mapper_.clock();
    const double r = filter_->config().resolution_m;
    const double unknown = filter_->config().unknown_p_occ;
    ParticleMap::Reader reader(map);
    bytes = core::serializeModel(
        mapper_, [&](std::int32_t x, std::int32_t y, std::int32_t last_step) -> std::optional<float> {
          // The particle cell holding this cell's centre, if this cell holds that one's
          // centre in turn (MapperTransitions' rule; both hold when the Mapper's origin is
          // on the filter's lattice, as it is unless configured otherwise).
          const double u = std::floor((grid.anchorX() + (x + 0.5) * grid.resolution()) / r);
          const double v = std::floor((grid.anchorY() + (y + 0.5) * grid.resolution()) / r);
          constexpr double kLimit = 2147483647.0;
          bool found = std::abs(u) < kLimit && std::abs(v) < kLimit;
          const auto px = static_cast<std::int32_t>(found ? u : 0.0);
          const auto py = static_cast<std::int32_t>(found ? v : 0.0);
          found = found && std::floor(grid.toLatticeX((px + 0.5) * r)) == x &&
                  std::floor(grid.toLatticeY((py + 0.5) * r)) == y;
          // The Mapper's step in the filter's steps, read at the step's middle.
          const std::int64_t step =
              filter_->clock().stepOf(mapper_clock.stepStart(last_step) + 0.5 * mapper_clock.timeStep());
          const std::int32_t particle_step = found ? reader.lastStep(px, py) : kNeverObserved;
          if (particle_step == kNeverObserved || particle_step > step) {
            ++counts.kept;
            return std::nullopt;
          }
          ++counts.replaced;
          return static_cast<float>(reader.predicted(px, py, step, filter_->transitions(), unknown));
        });
  }
  if (cells != nullptr) *cells = counts;
  return bytes;
}

std::vector<TrajectoryNode> CorrectedMapping::trajectory() const {
  return filter_->started() ? filter_->bestTrajectory() : std::vector<TrajectoryNode>{};
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
