#include "dynamic_occupancy_grid/core/pose/corrected_mapping.h"

#include <algorithm>
#include <array>
#include <bitset>
#include <chrono>
#include <cmath>
#include <future>
#include <limits>
#include <stdexcept>
#include <unordered_map>

#include "dynamic_occupancy_grid/core/layers/model_io.h"
#include "dynamic_occupancy_grid/core/pose/motion_model.h"
#include "dynamic_occupancy_grid/core/pose/particle_map.h"

namespace dynamic_occupancy_grid {
namespace core {

namespace {

constexpr double kPi = 3.14159265358979323846;
/// The longest beam the filter walks, in cells (PoseFilterConfig allows 1022).
constexpr double kMaxFilterRangeCells = 1000.0;

/// The correction in use changes only for one that moves the scan by more than this many
/// cells (CorrectedMapping's test).
constexpr double kSmallestCorrectionCells = 2.0;
/// The settled map is the Mapper's map as it was between this and twice this long ago
/// (seconds of sensor time).
constexpr double kSettledAge_s = 30.0;
/// The laser's travel counts a turn as this many metres per radian (where a correction
/// taken is spread over the scans mapped again).
constexpr double kTravelPerRadian_m = 1.0;
/// A correction taken is spread over at most this much of the laser's travel before it
/// (the scans since the last change or the settled checkpoint, if either is nearer): the
/// drift behind a correction need not have grown evenly, and spreading it evenly over a
/// long stretch moves scans that were right (a patrol's sudden heading error, measured:
/// pose_correction_real.md).
constexpr double kRemapTravel_m = 10.0;


Pose2D wrapped(Pose2D pose) {
  pose.yaw_rad = std::remainder(pose.yaw_rad, 2.0 * kPi);
  return pose;
}

/// How far the scan's laser position and beam ends (odometry frame; readings in
/// [range_min, min(range_max, max_range_m)]) lie apart in the map frame under the
/// corrections (map -> odom) `from` and `to`: the largest of those distances.
double largestMove(const Pose2D& from, const Pose2D& to, const Scan& scan, double max_range_m) {
  const auto move = [&](double x, double y) {
    const Pose2D a = composePose(from, Pose2D{x, y, 0.0});
    const Pose2D b = composePose(to, Pose2D{x, y, 0.0});
    return std::hypot(b.x_m - a.x_m, b.y_m - a.y_m);
  };
  const Pose2D& laser = scan.laser_pose;
  double largest = move(laser.x_m, laser.y_m);
  const double reach = std::min(scan.range_max_m, max_range_m);
  const double direction = scan.upside_down ? -1.0 : 1.0;
  for (std::size_t i = 0; i < scan.ranges_m.size(); ++i) {
    const double range = scan.ranges_m[i];
    if (!(range >= scan.range_min_m && range <= reach)) continue;
    const double angle =
        laser.yaw_rad + direction * (scan.angle_min_rad + static_cast<double>(i) * scan.angle_increment_rad);
    largest = std::max(largest, move(laser.x_m + range * std::cos(angle), laser.y_m + range * std::sin(angle)));
  }
  return largest;
}

std::uint64_t tileKey(std::int32_t tile_x, std::int32_t tile_y) {
  return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(tile_x)) << 32) |
         static_cast<std::uint32_t>(tile_y);
}

}  // namespace

struct CorrectedMapping::MapSnapshot {
  struct Cells {
    std::bitset<CellGrid::kTileCells> observed;
    std::bitset<CellGrid::kTileCells> occupied;
  };
  std::unordered_map<std::uint64_t, Cells> tiles;

  MapSnapshot(const Mapper& mapper, std::int64_t step) {
    mapper.grid().forEachTile([&](const CellGrid::Tile& tile) {
      Cells cells;
      for (int i = 0; i < CellGrid::kTileCells; ++i) {
        if (tile.last_step[i] == kNeverObserved) continue;
        cells.observed.set(i);
        const TransitionParams params{tile.p_occ_given_free[i], tile.p_free_given_occ[i]};
        if (predictOccupancy(tile.p_occ[i], params, step - tile.last_step[i]) > 0.5) cells.occupied.set(i);
      }
      if (cells.observed.any()) tiles.emplace(tileKey(tile.tile_x, tile.tile_y), cells);
    });
  }
  const Cells* find(std::int32_t x, std::int32_t y) const {
    const auto it = tiles.find(tileKey(x >> CellGrid::kTileBits, y >> CellGrid::kTileBits));
    return it == tiles.end() ? nullptr : &it->second;
  }
  bool observed(std::int32_t x, std::int32_t y) const {
    const Cells* cells = find(x, y);
    return cells != nullptr && cells->observed.test(static_cast<std::size_t>(CellGrid::offsetOf(x, y)));
  }
  bool occupied(std::int32_t x, std::int32_t y) const {
    const Cells* cells = find(x, y);
    return cells != nullptr && cells->occupied.test(static_cast<std::size_t>(CellGrid::offsetOf(x, y)));
  }
  /// The scan's log-likelihood in this map with the laser at `laser_pose` (map frame): the
  /// filter's weight (its beams and likelihood field, pose_filter.h). A beam whose end has
  /// no observed cell in the 3 x 3 around it counts as explained, as in the filter.
  double logLikelihood(const CellGrid& grid, const PoseFilterConfig& config,
                       const std::vector<std::array<double, 2>>& beams, const Pose2D& laser_pose) const {
    const double c = std::cos(laser_pose.yaw_rad);
    const double s = std::sin(laser_pose.yaw_rad);
    double sum = 0.0;
    for (const std::array<double, 2>& beam : beams) {
      const double u = grid.toLatticeX(laser_pose.x_m + c * beam[0] - s * beam[1]);
      const double v = grid.toLatticeY(laser_pose.y_m + s * beam[0] + c * beam[1]);
      const auto cx = static_cast<std::int32_t>(std::floor(u));
      const auto cy = static_cast<std::int32_t>(std::floor(v));
      bool mapped = false;
      for (std::int32_t dy = -1; dy <= 1 && !mapped; ++dy) {
        for (std::int32_t dx = -1; dx <= 1 && !mapped; ++dx) mapped = observed(cx + dx, cy + dy);
      }
      const double d =
          mapped ? grid.resolution() * nearestCellDistance(u, v, config.weight_max_distance_m / grid.resolution(),
                                                           [this](std::int32_t x, std::int32_t y) {
                                                             return occupied(x, y);
                                                           })
                 : 0.0;
      sum += beamLogLikelihood(config, d);
    }
    return sum;
  }
};

struct CorrectedMapping::Checkpoint {
  Checkpoint(const Mapper& mapper_then, std::int64_t snapshot_step, double travel_then, std::size_t first)
      : snapshot(std::make_shared<const MapSnapshot>(mapper_then, snapshot_step)),
        mapper(mapper_then),
        step(snapshot_step),
        travel(travel_then),
        first_scan(first) {}
  /// The Mapper mapped again, the snapshot kept.
  Checkpoint(const Checkpoint& taken, const Mapper& mapper_again)
      : snapshot(taken.snapshot), mapper(mapper_again), step(taken.step), travel(taken.travel), first_scan(taken.first_scan) {}
  std::shared_ptr<const MapSnapshot> snapshot;
  Mapper mapper;        ///< as it was before scan first_scan
  std::int64_t step;    ///< the snapshot's
  double travel;        ///< the laser's travel at scan first_scan
  std::size_t first_scan;
};

/// A re-mapping running beside the mapping (takeCorrection), taken at the next scan, once
/// the filter has updated on it (completeRemap): a fixed point, so that a replay maps the
/// same, which leaves it the filter's update to run in.
struct CorrectedMapping::Remap {
  struct Result {
    std::unique_ptr<Mapper> rebuilt;
    std::shared_ptr<const Checkpoint> newest;  ///< the newest checkpoint's Mapper mapped again; null: none
    std::unique_ptr<SequenceBuilder> recorded;  ///< its steps, where the Mapper records
  };
  std::future<Result> result;
  double adopt_after_s = 0.0;  ///< the stamp of the scan that took the correction
  std::size_t first_new = 0;           ///< the scan that took the correction
  std::int64_t checkpoint_step = 0;    ///< the checkpoint's last applied step
  std::uint64_t settings_revision = 0;  ///< the checkpoint Mapper's
};

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

CorrectedMapping::~CorrectedMapping() = default;

void CorrectedMapping::finish() {
  if (remap_) completeRemap();
}

bool CorrectedMapping::takeFinishedRemap() {
  if (!remap_ || remap_->result.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return false;
  completeRemap();
  return true;
}

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
  if (remap_ && odometry_scan.stamp_s > remap_->adopt_after_s) completeRemap();
  if (last_shifted_pose_) {
    travel_ += std::hypot(shifted.laser_pose.x_m - last_shifted_pose_->x_m,
                          shifted.laser_pose.y_m - last_shifted_pose_->y_m) +
               kTravelPerRadian_m * std::abs(std::remainder(shifted.laser_pose.yaw_rad - last_shifted_pose_->yaw_rad,
                                                            2.0 * kPi));
  }
  last_shifted_pose_ = shifted.laser_pose;
  if (result.update.updated) {
    refreshSnapshots();
    const Pose2D candidate = filter_->mapToOdometry();
    const bool passes = correctionPasses(candidate, shifted);
    if (passes && passed_last_update_) result.remapped = takeCorrection(candidate, odometry_scan.stamp_s);
    passed_last_update_ = passes && !passed_last_update_;
  }
  result.corrected = odometry_scan;
  result.corrected.laser_pose = wrapped(composePose(correction_, shifted.laser_pose));
  RecentScan recent;
  recent.shifted = shifted;
  recent.correction = correction_;
  recent.travel = travel_;
  if (result.update.updated) {
    TrajectoryNode node;
    node.stamp_s = odometry_scan.stamp_s;
    node.pose = result.corrected.laser_pose;
    node.odometry = shifted.laser_pose;
    trajectory_.push_back(node);
    recent.trajectory_node = trajectory_.size();
  }
  if (newest_) recent_.push_back(std::move(recent));  // nothing to map again before a checkpoint
  ++scans_seen_;
  result.mapped = mapper_.integrate(result.corrected);
  return result;
}

void CorrectedMapping::refreshSnapshots() {
  const std::optional<std::int64_t> now = mapper_.lastAppliedStep();
  if (!now || remap_) return;  // a checkpoint of the map being mapped again would be stale
  const auto age_steps = static_cast<std::int64_t>(std::ceil(kSettledAge_s / mapper_.config().time_step_s));
  if (newest_ && *now - newest_->step < age_steps) return;
  settled_ = newest_;
  newest_ = std::make_shared<const Checkpoint>(mapper_, *now, travel_, scans_seen_);
  const std::size_t keep_from = settled_ ? settled_->first_scan : newest_->first_scan;
  if (recent_.empty()) recent_first_ = keep_from;
  while (!recent_.empty() && recent_first_ < keep_from) {
    recent_.pop_front();
    ++recent_first_;
  }
}

std::size_t CorrectedMapping::takeCorrection(const Pose2D& correction, double stamp_s) {
  ++corrections_taken_;
  const Pose2D previous = correction_;
  correction_ = correction;
  if (remap_ || !settled_ || settled_->mapper.settingsRevision() != mapper_.settingsRevision() ||
      recent_first_ != settled_->first_scan) {
    last_taken_travel_ = travel_;
    return 0;
  }
  // The change spread by travel over the scans since the last change, the settled
  // checkpoint or kRemapTravel_m back, whichever is nearest: none at that start, all of it
  // for this scan (not in recent_ yet). The scans before the start are mapped again as they
  // were (the checkpoint holds the map before them).
  const double start = std::max({settled_->travel, last_taken_travel_, travel_ - kRemapTravel_m});
  last_taken_travel_ = travel_;
  const double span = travel_ - start;
  const double dx = correction.x_m - previous.x_m;
  const double dy = correction.y_m - previous.y_m;
  const double dyaw = std::remainder(correction.yaw_rad - previous.yaw_rad, 2.0 * kPi);
  std::vector<Scan> scans;
  scans.reserve(recent_.size());
  for (RecentScan& recent : recent_) {
    const double f = span > 0.0 ? std::clamp((recent.travel - start) / span, 0.0, 1.0) : 1.0;
    recent.correction = wrapped(Pose2D{recent.correction.x_m + f * dx, recent.correction.y_m + f * dy,
                                       recent.correction.yaw_rad + f * dyaw});
    scans.push_back(recent.shifted);
    scans.back().laser_pose = wrapped(composePose(recent.correction, recent.shifted.laser_pose));
    if (recent.trajectory_node > 0) trajectory_[recent.trajectory_node - 1].pose = scans.back().laser_pose;
  }
  // Mapped again beside the mapping, from the checkpoint (immutable, shared): the newest
  // checkpoint's Mapper where its first scan comes (this scan: after the last).
  const std::size_t newest_at = newest_->first_scan - recent_first_;
  const bool record = mapper_.recorder() != nullptr;
  remap_ = std::make_unique<Remap>();
  remap_->adopt_after_s = stamp_s;
  remap_->first_new = scans_seen_;
  remap_->checkpoint_step = *settled_->mapper.lastAppliedStep();
  remap_->settings_revision = settled_->mapper.settingsRevision();
  remap_->result = std::async(std::launch::async, [from = settled_, newest = newest_, scans = std::move(scans),
                                                   newest_at, record]() {
    Remap::Result result;
    result.rebuilt = std::make_unique<Mapper>(from->mapper);
    if (record) {
      result.recorded = std::make_unique<SequenceBuilder>();
      result.rebuilt->recordObservations(result.recorded.get());
    }
    for (std::size_t i = 0; i < scans.size(); ++i) {
      if (i == newest_at) result.newest = std::make_shared<const Checkpoint>(*newest, *result.rebuilt);
      result.rebuilt->integrate(scans[i]);
    }
    if (newest_at == scans.size()) result.newest = std::make_shared<const Checkpoint>(*newest, *result.rebuilt);
    result.rebuilt->recordObservations(nullptr);
    return result;
  });
  scans_remapped_ += recent_.size();
  return recent_.size();
}

void CorrectedMapping::completeRemap() {
  std::unique_ptr<Remap> remap = std::move(remap_);
  Remap::Result result = remap->result.get();
  // Settings changed since the checkpoint (the node's dynamic_reconfigure): the map goes on
  // as it is.
  if (mapper_.settingsRevision() != remap->settings_revision) return;
  Mapper& rebuilt = *result.rebuilt;
  if (SequenceBuilder* recorder = mapper_.recorder()) {
    recorder->dropAfter(static_cast<std::int32_t>(remap->checkpoint_step));
    if (result.recorded) recorder->append(*result.recorded);
    rebuilt.recordObservations(recorder);
  }
  // The scans since the correction was taken, as the live map got them.
  for (std::size_t index = remap->first_new; index < scans_seen_; ++index) {
    const RecentScan& recent = recent_[index - recent_first_];
    Scan scan = recent.shifted;
    scan.laser_pose = wrapped(composePose(recent.correction, recent.shifted.laser_pose));
    rebuilt.integrate(scan);
  }
  if (result.newest) newest_ = std::move(result.newest);
  mapper_.adopt(std::move(rebuilt));
}

bool CorrectedMapping::correctionPasses(const Pose2D& candidate, const Scan& shifted) const {
  if (!settled_) return false;
  const PoseFilterConfig& config = filter_->config();
  if (largestMove(correction_, candidate, shifted, config.max_range_m) <=
      kSmallestCorrectionCells * config.resolution_m) {
    return false;
  }
  const std::vector<std::array<double, 2>> beams = weightBeams(shifted, config.weight_beams);
  const CellGrid& grid = mapper_.grid();
  const MapSnapshot& settled = *settled_->snapshot;
  return settled.logLikelihood(grid, config, beams, composePose(candidate, shifted.laser_pose)) >
         settled.logLikelihood(grid, config, beams, composePose(correction_, shifted.laser_pose));
}

Pose2D CorrectedMapping::mapToOdometry() const {
  if (!filter_->started()) return start_correction_;
  return wrapped(composePose(correction_, start_correction_));
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

std::vector<TrajectoryNode> CorrectedMapping::trajectory() const { return trajectory_; }

}  // namespace core
}  // namespace dynamic_occupancy_grid
