#include "dynamic_occupancy_grid/core/grid/mapper.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

#include "dynamic_occupancy_grid/core/grid/scan_beams.h"
#include "dynamic_occupancy_grid/core/grid/traversal.h"

namespace dynamic_occupancy_grid {
namespace core {
namespace {

using ScanRecord = CellGrid::ScanRecord;

// The laser's turns count into its motion (Mapper::viewChangeSince) as the arc they sweep at
// this distance: a cell a metre away is seen along another line after a turn of one cell's
// width in metres.
constexpr double kViewRadiusM = 1.0;

// addSensorEvidence: the smallest lambda^k between a step and the next observation for the
// step to count (docs/online_learning.md, "The sensor model").
constexpr double kSensorModelMinCorrelation = 0.95;

void require(bool ok, const std::string& message) {
  if (!ok) throw std::invalid_argument(message);
}

bool isFinitePositive(double value) { return std::isfinite(value) && value > 0.0; }

std::int32_t maxCellsPerSide(const MapperConfig& config) {
  const double cells = std::ceil(config.max_map_size_m / config.resolution_m);
  // Whole tiles on both sides of the origin keep the limit on tile edges.
  const double unit = 2.0 * CellGrid::kTileSize;
  return static_cast<std::int32_t>(std::ceil(cells / unit) * unit);
}

std::optional<CellBox> fixedCells(const MapperConfig& config) {
  if (!config.fixed_bounds) return std::nullopt;
  CellBox box;
  box.min_x = 0;
  box.min_y = 0;
  // A size that is a whole number of cells up to rounding (2.1 m / 0.3 m) is that number.
  const auto cells = [&](double size_m) {
    return static_cast<std::int32_t>(std::ceil(size_m / config.resolution_m - 1e-9));
  };
  box.max_x = cells(config.width_m) - 1;
  box.max_y = cells(config.height_m) - 1;
  return box;
}

const MapperConfig& validated(const MapperConfig& config) {
  config.validate();
  return config;
}

}  // namespace

void MapperConfig::validate() const {
  require(isFinitePositive(resolution_m), "resolution must be > 0 m, got " + std::to_string(resolution_m));
  require(isFinitePositive(time_step_s), "time_step must be > 0 s, got " + std::to_string(time_step_s));
  require(prior_transitions.isValid(),
          "prior p_occ_given_free and p_free_given_occ must be in [0, 1], got " +
              std::to_string(prior_transitions.p_occ_given_free) + " and " +
              std::to_string(prior_transitions.p_free_given_occ));
  require(initial_p_occ > 0.0 && initial_p_occ < 1.0,
          "initial_p_occ must be in (0, 1), got " + std::to_string(initial_p_occ));
  require(static_clamp.min_log_odds < 0.0 && static_clamp.max_log_odds > 0.0,
          "static map clamping needs min_log_odds < 0 < max_log_odds");
  require(std::isfinite(max_free_range_m) && max_free_range_m >= 0.0,
          "max_free_range must be >= 0 m, got " + std::to_string(max_free_range_m));
  require(std::isfinite(origin_x_m) && std::isfinite(origin_y_m), "map origin must be finite");
  require(isFinitePositive(max_map_size_m) && max_map_size_m / resolution_m < 1.0e8,
          "max_map_size must be > 0 m and below 1e8 cells per side, got " +
              std::to_string(max_map_size_m));
  if (fixed_bounds) {
    require(isFinitePositive(width_m) && isFinitePositive(height_m),
            "fixed bounds need width > 0 m and height > 0 m");
    require(width_m <= max_map_size_m && height_m <= max_map_size_m,
            "fixed width and height must not exceed max_map_size");
  }
  online_em.validate();
  kinds.validate();
  require(std::isfinite(sensor_model_prior_weight) && sensor_model_prior_weight > 0.0,
          "sensor_model_prior_weight must be > 0, got " + std::to_string(sensor_model_prior_weight));
  require(sensor_model_p_min > 0.0 && sensor_model_p_min <= 0.4,
          "sensor_model_p_min must be in (0, 0.4], got " + std::to_string(sensor_model_p_min));
  require(sensor_model_mixed_step_probability >= 0.0 && sensor_model_mixed_step_probability <= 0.5,
          "sensor_model_mixed_step_probability must be in [0, 0.5], got " +
              std::to_string(sensor_model_mixed_step_probability));
  require(online_em.min_observed_steps <= std::numeric_limits<std::uint16_t>::max(),
          "online_em min_observed_steps must be <= 65535 (the grid counts up to that), got " +
              std::to_string(online_em.min_observed_steps));
  // Throws with its own message for a bad sensor model.
  static_cast<void>(ObservationModel(p_hit_given_occ, p_hit_given_free));
}

Mapper::Mapper(const MapperConfig& config)
    : config_(validated(config)),
      sensor_(config.p_hit_given_occ, config.p_hit_given_free, config.sensor_model_mixed_step_probability),
      static_sensor_(config.p_hit_given_occ, config.p_hit_given_free),
      clock_(config.time_step_s),
      grid_(config.resolution_m, config.origin_x_m, config.origin_y_m, fixedCells(config),
            maxCellsPerSide(config),
            CellGrid::CellDefaults{static_cast<float>(config.prior_transitions.p_occ_given_free),
                                   static_cast<float>(config.prior_transitions.p_free_given_occ)}),
      kinds_(config.kinds, std::max(config.online_em.p_min, 1e-6), std::min(config.online_em.p_max, 0.5)) {}

Mapper::Mapper(const Mapper& other)
    : config_(other.config_),
      sensor_(other.sensor_),
      static_sensor_(other.static_sensor_),
      clock_(other.clock_),
      grid_(other.grid_),
      gathering_step_(other.gathering_step_),
      last_applied_step_(other.last_applied_step_),
      touched_tiles_(other.touched_tiles_),
      scan_id_(other.scan_id_),
      changed_cells_(other.changed_cells_),
      tile_versions_(other.tile_versions_),
      kinds_(other.kinds_),
      sensor_stats_(other.sensor_stats_),
      motion_cells_(other.motion_cells_),
      last_laser_pose_(other.last_laser_pose_),
      motion_at_step_(other.motion_at_step_),
      motion_step_(other.motion_step_),
      settings_revision_(other.settings_revision_) {
  // The step being gathered: the same tiles of this grid.
  for (TouchedTile& touched : touched_tiles_) {
    touched.tile = grid_.findTile(touched.tile->cellX(0), touched.tile->cellY(0));
  }
}

void Mapper::adopt(Mapper&& rebuilt) {
  CellBox changed = changed_cells_;
  changed.include(grid_.bounds());
  changed.include(rebuilt.changed_cells_);
  changed.include(rebuilt.grid_.bounds());
  TileVersions versions = std::move(tile_versions_);
  SequenceBuilder* recorder = recorder_;
  const std::uint64_t revision = settings_revision_;
  *this = std::move(rebuilt);
  tile_versions_ = std::move(versions);
  tile_versions_.bumpAll();
  recorder_ = recorder;
  changed_cells_ = changed;
  settings_revision_ = revision;
}

ScanResult Mapper::integrate(const Scan& scan) {
  ScanResult result;
  const auto reject = [&result](ScanStatus status, std::string error) {
    result.status = status;
    result.error = std::move(error);
    return result;
  };
  if (const auto error = scanFieldsError(scan)) return reject(ScanStatus::kRejectedInvalid, *error);
  const Pose2D& pose = scan.laser_pose;
  const double u0 = grid_.toLatticeX(pose.x_m);
  const double v0 = grid_.toLatticeY(pose.y_m);
  if (std::abs(u0) > kMaxLatticeCoordinate || std::abs(v0) > kMaxLatticeCoordinate) {
    return reject(ScanStatus::kRejectedInvalid, "laser pose is too far from the map origin");
  }

  // The first accepted scan starts step 0.
  const std::int64_t step = clock_.origin() ? clock_.stepOf(scan.stamp_s) : 0;
  // Scans may arrive out of order within the step being gathered, never before it, never
  // into a step already applied, and never before step 0 (restartClockAt anchors step 0, or
  // the step after the last applied one, at a stamp; nothing may come before it).
  const std::int64_t first_allowed =
      gathering_step_ ? *gathering_step_ : (last_applied_step_ ? *last_applied_step_ + 1 : 0);
  if (step < first_allowed) {
    return reject(ScanStatus::kRejectedTimeBackwards,
                  "stamp " + std::to_string(scan.stamp_s) + " s is in step " + std::to_string(step) +
                      ", before the first step still open (" + std::to_string(first_allowed) + ")");
  }
  if (step > std::numeric_limits<std::int32_t>::max() - 1) {
    return reject(ScanStatus::kRejectedInvalid, "stamp too far after the first one for time_step");
  }

  // Beam end points in lattice coordinates (the reading rules: scan_beams.h).
  BeamRules rules;
  rules.cells_per_m = 1.0 / config_.resolution_m;
  rules.max_free_range_m = config_.max_free_range_m;
  rules.max_beam_m = 1.5 * maxCellsPerSide(config_) * config_.resolution_m;
  std::vector<BeamEnd> beams;
  BeamCounts counts;
  CellBox box;
  if (const auto bad_beam = beamEnds(scan, u0, v0, rules, beams, counts, box)) {
    return reject(ScanStatus::kRejectedInvalid, "beam " + std::to_string(*bad_beam) + " ends too far from the map origin");
  }
  result.beams_hit = counts.hit;
  result.beams_no_return = counts.no_return;
  result.beams_ignored = counts.ignored;

  // Accepted from here on: the step bookkeeping may change.
  clock_.startAt(scan.stamp_s);
  if (gathering_step_ && step > *gathering_step_) applyGatheredStep();
  gathering_step_ = step;
  if (last_laser_pose_) {
    const double turn = std::remainder(pose.yaw_rad - last_laser_pose_->yaw_rad, 2.0 * M_PI);
    motion_cells_ += (std::hypot(pose.x_m - last_laser_pose_->x_m, pose.y_m - last_laser_pose_->y_m) +
                      kViewRadiusM * std::abs(turn)) /
                     config_.resolution_m;
  }
  last_laser_pose_ = pose;
  nextScanId();
  grid_.reserve(box);

  // Consecutive cells of a beam mostly share a tile: remember the last one.
  CellGrid::Tile* cached_tile = nullptr;
  std::int32_t cached_tile_x = 0;
  std::int32_t cached_tile_y = 0;
  bool cached_tile_straddles = false;
  const auto tile_of = [&](std::int32_t x, std::int32_t y) -> CellGrid::Tile* {
    const std::int32_t tile_x = x >> CellGrid::kTileBits;
    const std::int32_t tile_y = y >> CellGrid::kTileBits;
    if (cached_tile == nullptr || tile_x != cached_tile_x || tile_y != cached_tile_y) {
      cached_tile = grid_.tileForWriting(x, y);
      if (cached_tile == nullptr) return nullptr;  // outside the map: do not cache
      cached_tile_x = tile_x;
      cached_tile_y = tile_y;
      cached_tile_straddles = !grid_.tileInsideLimits(tile_x, tile_y);
    } else if (cached_tile_straddles && !grid_.insideLimits(x, y)) {
      // Only a tile crossing the map's limits needs the check per cell.
      return nullptr;
    }
    return cached_tile;
  };
  // A beam's misses are counted kMissLookahead cells behind the traversal, which prefetches
  // each cell's record when it reaches it: far from the sensor every visit is a cache miss,
  // and this keeps that many of them in flight. The cells are counted in the same order.
  constexpr std::size_t kMissLookahead = 32;
  std::array<std::pair<CellGrid::Tile*, int>, kMissLookahead> pending;
  std::size_t pending_count = 0;
  for (const BeamEnd& beam : beams) {
    const CellXY end = traverseSegment(u0, v0, beam.u1, beam.v1, [&](std::int32_t x, std::int32_t y) {
      CellGrid::Tile* tile = tile_of(x, y);
      if (tile == nullptr) {
        ++result.cells_outside;
        return;
      }
      const int offset = CellGrid::offsetOf(x, y);
      __builtin_prefetch(&tile->scan_record[offset], 1);
      auto& slot = pending[pending_count % kMissLookahead];
      if (pending_count >= kMissLookahead) markMiss(*slot.first, slot.second);
      slot = {tile, offset};
      ++pending_count;
    });
    CellGrid::Tile* tile = tile_of(end.x, end.y);
    for (std::size_t k = pending_count > kMissLookahead ? pending_count - kMissLookahead : 0; k < pending_count; ++k) {
      const auto& slot = pending[k % kMissLookahead];
      markMiss(*slot.first, slot.second);
    }
    pending_count = 0;
    if (tile == nullptr) {
      ++result.cells_outside;
    } else if (beam.hit) {
      markHit(*tile, CellGrid::offsetOf(end.x, end.y));
    } else {
      markMiss(*tile, CellGrid::offsetOf(end.x, end.y));
    }
  }
  return result;
}

void Mapper::nextScanId() {
  // Records hold the id in 31 bits; on wrap-around forget all marks (keeping the step's
  // counts) so no stale mark can equal a new id (once in 2^31 scans).
  if (scan_id_ == ScanRecord::kIdMask) {
    grid_.forEachTile([](CellGrid::Tile& tile) {
      for (std::uint64_t& record : tile.scan_record) record &= ~ScanRecord::kMarkMask;
    });
    scan_id_ = 0;
  }
  ++scan_id_;
}

void Mapper::addTouched(CellGrid::Tile& tile, int offset) {
  if (tile.touched_slot < 0) {
    tile.touched_slot = static_cast<std::int32_t>(touched_tiles_.size());
    touched_tiles_.push_back(TouchedTile{&tile, {}});
  }
  touched_tiles_[tile.touched_slot].cells[offset >> 6] |= std::uint64_t{1} << (offset & 63);
}

void Mapper::markMiss(CellGrid::Tile& tile, int offset) {
  std::uint64_t& slot = tile.scan_record[offset];
  const std::uint64_t record = slot;
  if (ScanRecord::scanId(record) == scan_id_) return;  // this scan already counted it
  if (!ScanRecord::gathered(record)) addTouched(tile, offset);
  const std::uint32_t misses = ScanRecord::misses(record);
  slot = ScanRecord::make(scan_id_, false, ScanRecord::hits(record),
                          misses + (misses < ScanRecord::kMaxCount ? 1 : 0));
}

void Mapper::markHit(CellGrid::Tile& tile, int offset) {
  std::uint64_t& slot = tile.scan_record[offset];
  const std::uint64_t record = slot;
  std::uint32_t hits = ScanRecord::hits(record);
  std::uint32_t misses = ScanRecord::misses(record);
  if (ScanRecord::scanId(record) == scan_id_) {
    if (ScanRecord::hit(record)) return;  // already a hit in this scan
    // Missed earlier in this scan: the hit wins, the miss is taken back.
    if (misses > 0) --misses;
  } else if (!ScanRecord::gathered(record)) {
    addTouched(tile, offset);
  }
  if (hits < ScanRecord::kMaxCount) ++hits;
  slot = ScanRecord::make(scan_id_, true, hits, misses);
}

void Mapper::applyGatheredStep() {
  if (!gathering_step_) return;
  const auto step = static_cast<std::int32_t>(*gathering_step_);
  motion_at_step_[motionSlot(step)] = motion_cells_;
  motion_step_[motionSlot(step)] = step;
  for (const TouchedTile& touched : touched_tiles_) {
    CellGrid::Tile& tile = *touched.tile;
    tile_versions_.bump(tile.tile_x, tile.tile_y);
    for (int word = 0; word < static_cast<int>(touched.cells.size()); ++word) {
      for (std::uint64_t bits = touched.cells[word]; bits != 0; bits &= bits - 1) {
        applyCellStep(tile, 64 * word + __builtin_ctzll(bits), step);
      }
    }
    tile.touched_slot = -1;
  }
  touched_tiles_.clear();
  last_applied_step_ = gathering_step_;
  if (config_.learn_sensor_model) updateSensorModel();
  if (config_.learn_transitions && config_.learner == TransitionLearner::kKinds) kinds_.update();
}

void Mapper::applyCellStep(CellGrid::Tile& tile, int i, std::int32_t step) {
  const std::uint64_t record = tile.scan_record[i];
  tile.scan_record[i] = record & ScanRecord::kMarkMask;
  applyCellEvidence(tile, i, step, ScanRecord::hits(record), ScanRecord::misses(record));
}

void Mapper::applyCellEvidence(CellGrid::Tile& tile, int i, std::int32_t step, std::uint32_t hits,
                               std::uint32_t misses) {
  const double evidence = sensor_.logLikelihoodRatio(hits, misses);
  const bool kinds = config_.learner == TransitionLearner::kKinds;
  const bool observed_before = tile.last_step[i] != kNeverObserved;
  if (config_.learn_transitions && kinds) {
    // The evidence's two likelihoods once, for the sensor model's statistics, the pair and
    // the filter.
    const KindEvidence kind_evidence(evidence);
    const double view_change = observed_before ? viewChangeSince(tile.last_step[i]) : 1.0;
    if (config_.learn_sensor_model && observed_before) {
      addKindsSensorEvidence(tile, i, step, kind_evidence, view_change);
    }
    learnKindsStep(tile, i, step, kind_evidence, view_change);
  } else {
    if (config_.learn_sensor_model && observed_before) addSensorEvidence(tile, i, step, evidence);
    if (config_.learn_transitions) {
      learnStep(tile, i, step, evidence);
    } else {
      const TransitionParams params{tile.p_occ_given_free[i], tile.p_free_given_occ[i]};
      const std::int32_t last = tile.last_step[i];
      // The belief just before this step's transition: the prior for a new cell, otherwise
      // the stored belief carried over the unobserved steps in closed form (THEORY.md §3).
      const double before = last == kNeverObserved
                                ? config_.initial_p_occ
                                : predictOccupancy(tile.p_occ[i], params, std::int64_t{step} - 1 - last);
      tile.p_occ[i] = static_cast<float>(filterStep(before, params, evidence));
      if (kinds) {
        // The kind posterior stays as it was; the state follows the filter, so that learning
        // turned on again goes on from this belief.
        for (int k = 0; k < kKindCount; ++k) {
          const double mass = last == kNeverObserved ? kinds_.weight(k)
                                                     : double{tile.em_stats[2 * k][i]} + tile.em_stats[2 * k + 1][i];
          tile.em_stats[2 * k][i] = static_cast<float>(mass * tile.p_occ[i]);
          tile.em_stats[2 * k + 1][i] = static_cast<float>(mass * (1.0 - tile.p_occ[i]));
        }
      }
    }
  }
  // The static baseline weighs the step with the configured sensor model, learned or not:
  // it stays the textbook grid its clamp was chosen for.
  const double static_evidence = static_sensor_.logLikelihoodRatio(hits, misses);
  tile.log_odds[i] = static_cast<float>(updateLogOdds(tile.log_odds[i], static_evidence, config_.static_clamp));
  if (recorder_ != nullptr) recorder_->add(tile.cellX(i), tile.cellY(i), step, hits, misses);
  tile.last_step[i] = step;
  tile.last_hits[i] = static_cast<std::uint8_t>(std::min<std::uint32_t>(hits, 255));
  tile.last_misses[i] = static_cast<std::uint8_t>(std::min<std::uint32_t>(misses, 255));
  changed_cells_.include(tile.cellX(i), tile.cellY(i));
}

void Mapper::addSensorEvidence(const CellGrid::Tile& tile, int i, std::int32_t step, double evidence) {
  // The cell's previous observed step (belief q after it, evidence last_hits / last_misses)
  // weighed by p(x_last | z up to and including this step): q_i * sum_m A^k(i, m) p(z|m),
  // k = the transitions in between (THEORY.md §3's closed form), p(z|m) as a ratio.
  const std::uint32_t hits = tile.last_hits[i];
  const std::uint32_t trials = hits + tile.last_misses[i];
  if (trials == 0) return;
  const TransitionParams params{tile.p_occ_given_free[i], tile.p_free_given_occ[i]};
  const std::int64_t k = std::int64_t{step} - tile.last_step[i];
  // Only where the next observation says much about the state then: lambda^k >= 0.95 (the
  // cell is expected to keep its state in between). Elsewhere the smoothed state is mostly
  // the step's own evidence, and counting it would teach the model what it already assumes.
  // A learning cell still on the prior transitions (fewer than min_observed_steps) has not
  // shown yet how fast it changes: it waits.
  if ((config_.learn_transitions && tile.observed_steps[i] < config_.online_em.min_observed_steps) ||
      lambdaPower(params, k) < kSensorModelMinCorrelation) {
    return;
  }
  const double occ_to_occ = predictOccupancy(1.0, params, k);
  const double free_to_occ = predictOccupancy(0.0, params, k);
  // Likelihoods of this step's evidence scaled so that the larger is 1.
  const double like_occ = evidence >= 0.0 ? 1.0 : std::exp(evidence);
  const double like_free = evidence >= 0.0 ? std::exp(-evidence) : 1.0;
  const double q = tile.p_occ[i];
  const double w_occ = q * (occ_to_occ * like_occ + (1.0 - occ_to_occ) * like_free);
  const double w_free = (1.0 - q) * (free_to_occ * like_occ + (1.0 - free_to_occ) * like_free);
  const double p_occ = w_occ / (w_occ + w_free);
  sensor_stats_.trials[0] += p_occ * trials;
  sensor_stats_.hits[0] += p_occ * hits;
  sensor_stats_.trials[1] += (1.0 - p_occ) * trials;
  sensor_stats_.hits[1] += (1.0 - p_occ) * hits;
}

void Mapper::updateSensorModel() {
  // The M-step of the shared emissions: hits over beam ends per state, with the configured
  // model as sensor_model_prior_weight beam ends of each state.
  if (sensor_stats_.trials[0] == 0.0 && sensor_stats_.trials[1] == 0.0) {
    sensor_ = ObservationModel(config_.p_hit_given_occ, config_.p_hit_given_free,
                               config_.sensor_model_mixed_step_probability);  // nothing learned
    return;
  }
  const double w = config_.sensor_model_prior_weight;
  const double lo = config_.sensor_model_p_min;
  const double occ = std::clamp((sensor_stats_.hits[0] + w * config_.p_hit_given_occ) / (sensor_stats_.trials[0] + w),
                                lo, 1.0 - lo);
  const double free = std::clamp(
      (sensor_stats_.hits[1] + w * config_.p_hit_given_free) / (sensor_stats_.trials[1] + w), lo, 1.0 - lo);
  // A hit must stay evidence for "occupied": keep the last model otherwise.
  if (occ >= free + 0.05) sensor_ = ObservationModel(occ, free, config_.sensor_model_mixed_step_probability);
}

void Mapper::restoreSensorModelStats(const SensorModelStats& stats) {
  ++settings_revision_;
  for (int state = 0; state < 2; ++state) {
    if (!std::isfinite(stats.trials[state]) || !std::isfinite(stats.hits[state]) || stats.hits[state] < 0.0 ||
        stats.hits[state] > stats.trials[state] * (1.0 + 1e-12)) {
      throw std::invalid_argument("restoreSensorModelStats: sums must be finite, >= 0, hits at most trials");
    }
  }
  sensor_stats_ = stats;
  updateSensorModel();
}

void Mapper::storeStats(CellGrid::Tile& tile, int i, const TransitionStats& stats) {
  for (std::size_t k = 0; k < stats.s.size(); ++k) tile.em_stats[k][i] = static_cast<float>(stats.s[k]);
}

void Mapper::learnStep(CellGrid::Tile& tile, int i, std::int32_t step, double evidence) {
  // THEORY.md §6: the statistics and the belief are carried over the unobserved steps in
  // closed form, then the observed step and the M-step (online_em.h, onlineLearnStep).
  OnlineCell cell;
  const std::int32_t last = tile.last_step[i];
  std::int64_t gap = 0;
  const TransitionParams& prior = config_.prior_transitions;
  if (last == kNeverObserved) {
    cell = newOnlineCell(prior, config_.initial_p_occ, config_.online_em);
  } else {
    cell.p_occ = tile.p_occ[i];
    for (std::size_t k = 0; k < cell.stats.s.size(); ++k) cell.stats.s[k] = tile.em_stats[k][i];
    cell.observed_steps = tile.observed_steps[i];
    cell.params = TransitionParams{tile.p_occ_given_free[i], tile.p_free_given_occ[i]};
    gap = std::int64_t{step} - 1 - last;
  }
  onlineLearnStep(cell, gap, evidence, prior, config_.online_em);
  tile.p_occ[i] = static_cast<float>(cell.p_occ);
  storeStats(tile, i, cell.stats);
  tile.observed_steps[i] = static_cast<std::uint16_t>(
      std::min<std::uint32_t>(cell.observed_steps, std::numeric_limits<std::uint16_t>::max()));
  tile.p_occ_given_free[i] = static_cast<float>(cell.params.p_occ_given_free);
  tile.p_free_given_occ[i] = static_cast<float>(cell.params.p_free_given_occ);
}

double Mapper::viewChangeSince(std::int32_t last_step) const {
  const std::size_t slot = motionSlot(last_step);
  if (!gathering_step_ || motion_step_[slot] != last_step) return 1.0;
  return std::min(1.0, motion_cells_ - motion_at_step_[slot]);
}

void Mapper::learnKindsStep(CellGrid::Tile& tile, int i, std::int32_t step, const KindEvidence& evidence,
                            double view_change) {
  const std::int32_t last = tile.last_step[i];
  const bool first = last == kNeverObserved;
  KindJoint joint;
  std::int64_t gap = 0;
  if (first) {
    joint = kinds_.newCell(config_.initial_p_occ);
  } else {
    for (int k = 0; k < 2 * kKindCount; ++k) joint.p[k] = tile.em_stats[k][i];
    gap = std::int64_t{step} - 1 - last;
  }
  std::array<double, kKindCount> before{};
  if (!first) {
    for (int k = 0; k < kKindCount; ++k) before[k] = joint.kind(k);
  }
  // The pair (its state at its last observed step, its state now) teaches the kinds
  // (cell_kinds.h), from the joint before the gap is crossed.
  if (!first) kinds_.addPair(joint, gap + 1, evidence, view_change);
  kinds_.skip(joint, gap);
  tile.p_occ[i] = static_cast<float>(kinds_.observe(joint, gap, evidence, view_change));
  std::array<double, kKindCount> delta{};
  for (int k = 0; k < kKindCount; ++k) delta[k] = joint.kind(k) - before[k];
  kinds_.addMembership(delta, first);
  for (int k = 0; k < 2 * kKindCount; ++k) tile.em_stats[k][i] = static_cast<float>(joint.p[k]);
  const TransitionParams params = kinds_.summary(joint);
  tile.p_occ_given_free[i] = static_cast<float>(params.p_occ_given_free);
  tile.p_free_given_occ[i] = static_cast<float>(params.p_free_given_occ);
  if (tile.observed_steps[i] < std::numeric_limits<std::uint16_t>::max()) ++tile.observed_steps[i];
}

void Mapper::addKindsSensorEvidence(const CellGrid::Tile& tile, int i, std::int32_t step,
                                    const KindEvidence& evidence, double view_change) {
  // As addSensorEvidence, per kind: p(k, x_last = s | z up to this step) ∝ p(k, s | z up to
  // last) * sum_m A_k^n(s, m) p(z|m), n the transitions in between, counted only for the
  // kinds expected to keep their state in between (lambda_k^n >= 0.95), and only once the
  // cell has shown what it is (min_observed_steps).
  const std::uint32_t hits = tile.last_hits[i];
  const std::uint32_t trials = hits + tile.last_misses[i];
  if (trials == 0 || tile.observed_steps[i] < config_.online_em.min_observed_steps) return;
  const std::int64_t n = std::int64_t{step} - tile.last_step[i];
  const double like_occ = evidence.occ;
  const double like_free = evidence.free;
  double counted[2] = {0.0, 0.0};
  double total = 0.0;
  for (int k = 0; k < kKindCount; ++k) {
    const double lambda_n = kinds_.lambdaPower(k, n);
    const double occ_to_occ = kinds_.occupiedAfter(k, 0, n, view_change);
    const double free_to_occ = kinds_.occupiedAfter(k, 1, n, view_change);
    const double w_occ = tile.em_stats[2 * k][i] * (occ_to_occ * like_occ + (1.0 - occ_to_occ) * like_free);
    const double w_free = tile.em_stats[2 * k + 1][i] * (free_to_occ * like_occ + (1.0 - free_to_occ) * like_free);
    total += w_occ + w_free;
    if (lambda_n >= kSensorModelMinCorrelation) {
      counted[0] += w_occ;
      counted[1] += w_free;
    }
  }
  if (!(total > 0.0)) return;
  for (int s = 0; s < 2; ++s) {
    const double p = counted[s] / total;
    sensor_stats_.trials[s] += p * trials;
    sensor_stats_.hits[s] += p * hits;
  }
}

void Mapper::finishStep() {
  applyGatheredStep();
  gathering_step_.reset();
}

double Mapper::beliefAt(std::int32_t x, std::int32_t y, std::int64_t step) const {
  const std::optional<CellState> state = grid_.cell(x, y);
  if (!state) return std::numeric_limits<double>::quiet_NaN();
  const TransitionParams params{state->p_occ_given_free, state->p_free_given_occ};
  return predictOccupancy(state->p_occ, params, step - state->last_step);
}

void Mapper::replayObservations(const ObservationSequences& sequences) {
  if (gathering_step_) throw std::logic_error("replayObservations: the mapper is gathering a step");
  if (config_.learn_transitions || config_.learn_sensor_model) {
    throw std::logic_error("replayObservations: needs learn_transitions and learn_sensor_model off");
  }
  // Checked before anything changes.
  const std::int64_t first_allowed = last_applied_step_ ? *last_applied_step_ + 1 : 0;
  std::optional<std::int64_t> newest = last_applied_step_;
  CellBox box;
  for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
    const CellXY xy = sequences.cell(c);
    const auto where = [&xy] { return "(" + std::to_string(xy.x) + ", " + std::to_string(xy.y) + ")"; };
    if (!grid_.insideLimits(xy.x, xy.y)) {
      throw std::invalid_argument("replayObservations: cell " + where() + " is outside the map's limits");
    }
    if (sequences.begin(c)->step < first_allowed) {
      throw std::invalid_argument("replayObservations: cell " + where() + " has an observation in step " +
                                  std::to_string(sequences.begin(c)->step) + ", already applied");
    }
    const CellGrid::Tile* tile = grid_.findTile(xy.x, xy.y);
    if (tile != nullptr && tile->last_step[CellGrid::offsetOf(xy.x, xy.y)] >= sequences.begin(c)->step) {
      throw std::invalid_argument("replayObservations: cell " + where() + " was observed in a later step");
    }
    newest = std::max<std::int64_t>(newest.value_or(0), sequences.end(c)[-1].step);
    box.include(xy.x, xy.y);
  }
  grid_.reserve(box);
  for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
    const CellXY xy = sequences.cell(c);
    CellGrid::Tile& tile = *grid_.tileForWriting(xy.x, xy.y);
    tile_versions_.bump(tile.tile_x, tile.tile_y);
    const int i = CellGrid::offsetOf(xy.x, xy.y);
    for (const StepObservation* o = sequences.begin(c); o != sequences.end(c); ++o) {
      applyCellEvidence(tile, i, o->step, o->hits, o->misses);
    }
  }
  last_applied_step_ = newest;
}

void Mapper::restartClockAt(double stamp_s) {
  ++settings_revision_;
  if (!std::isfinite(stamp_s)) throw std::invalid_argument("restartClockAt: stamp is not finite");
  finishStep();
  clock_.anchor(stamp_s, last_applied_step_ ? *last_applied_step_ + 1 : 0);
}

OfflineEmApplied Mapper::applyOfflineEm(const ObservationSequences& sequences, const OfflineEmResult& result,
                                        bool use_final_beliefs) {
  ++settings_revision_;
  if (result.params.size() != sequences.cellCount() || result.final_p_occ.size() != sequences.cellCount() ||
      result.final_step.size() != sequences.cellCount()) {
    throw std::invalid_argument("applyOfflineEm: the result does not belong to these sequences");
  }
  if (result.cancelled) throw std::invalid_argument("applyOfflineEm: the offline EM run was cancelled");
  const double memory = config_.online_em.learning_rate_floor > 0.0
                            ? 1.0 / config_.online_em.learning_rate_floor
                            : std::numeric_limits<double>::infinity();
  OfflineEmApplied applied;
  for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
    const CellXY xy = sequences.cell(c);
    CellGrid::Tile* tile = grid_.findTile(xy.x, xy.y);
    const int i = CellGrid::offsetOf(xy.x, xy.y);
    if (tile == nullptr || tile->last_step[i] == kNeverObserved) {
      ++applied.cells_not_in_map;
      continue;
    }
    const TransitionParams& params = result.params[c];
    if (use_final_beliefs) {
      tile->p_occ[i] = static_cast<float>(result.final_p_occ[c]);
      tile->last_step[i] = result.final_step[c];
    }
    if (config_.learner == TransitionLearner::kKinds) {
      // The cell keeps its kind posterior; its state becomes the offline filter's, and it
      // shows the offline transitions until its next observed step, when its kinds take over.
      if (use_final_beliefs) {
        for (int k = 0; k < kKindCount; ++k) {
          const double mass = double{tile->em_stats[2 * k][i]} + tile->em_stats[2 * k + 1][i];
          tile->em_stats[2 * k][i] = static_cast<float>(mass * tile->p_occ[i]);
          tile->em_stats[2 * k + 1][i] = static_cast<float>(mass * (1.0 - tile->p_occ[i]));
        }
      }
      tile->p_occ_given_free[i] = static_cast<float>(params.p_occ_given_free);
      tile->p_free_given_occ[i] = static_cast<float>(params.p_free_given_occ);
      changed_cells_.include(xy.x, xy.y);
      ++applied.cells_applied;
      continue;
    }
    // The steps the result saw, split over the two from-states.
    const double span = static_cast<double>(sequences.end(c)[-1].step) - sequences.begin(c)->step + 1.0;
    const TransitionStats stats = priorStats(params, 0.5 * std::min(span, memory), tile->p_occ[i]);
    storeStats(*tile, i, stats);
    // The learned transitions are used from now on, not the prior.
    tile->observed_steps[i] = static_cast<std::uint16_t>(
        std::max<std::uint32_t>(tile->observed_steps[i], config_.online_em.min_observed_steps));
    tile->p_occ_given_free[i] = static_cast<float>(params.p_occ_given_free);
    tile->p_free_given_occ[i] = static_cast<float>(params.p_free_given_occ);
    changed_cells_.include(xy.x, xy.y);
    ++applied.cells_applied;
  }
  tile_versions_.bumpAll();
  // A sensor model offline EM learned with the transitions is the one they belong to: its
  // sums become this mapper's (online learning goes on from them; the configured start and
  // the static baseline stay).
  if (result.sensor_trials[0] + result.sensor_trials[1] > 0.0) {
    SensorModelStats stats;
    for (int state = 0; state < 2; ++state) {
      stats.trials[state] = result.sensor_trials[state];
      stats.hits[state] = std::min(result.sensor_hits[state], result.sensor_trials[state]);
    }
    restoreSensorModelStats(stats);
  }
  return applied;
}

void Mapper::restoreTime(std::optional<double> clock_origin_s, std::optional<std::int64_t> last_applied_step) {
  ++settings_revision_;
  if (clock_.origin() || gathering_step_ || last_applied_step_) {
    throw std::logic_error("restoreTime: only a mapper that has integrated nothing can be restored");
  }
  if (last_applied_step && !clock_origin_s) {
    throw std::invalid_argument("restoreTime: a last applied step needs a clock origin");
  }
  if (clock_origin_s && !std::isfinite(*clock_origin_s)) {
    throw std::invalid_argument("restoreTime: clock origin is not finite");
  }
  if (last_applied_step &&
      (*last_applied_step < 0 || *last_applied_step > std::numeric_limits<std::int32_t>::max() - 1)) {
    throw std::invalid_argument("restoreTime: last applied step out of range");
  }
  if (clock_origin_s) clock_.restoreOrigin(*clock_origin_s);
  last_applied_step_ = last_applied_step;
}

void Mapper::restoreCell(std::int32_t x, std::int32_t y, const CellState& state) {
  ++settings_revision_;
  const auto probability = [](float p) { return p >= 0.0f && p <= 1.0f; };
  if (state.last_step == kNeverObserved || !last_applied_step_ || state.last_step > *last_applied_step_) {
    throw std::invalid_argument("restoreCell: cell (" + std::to_string(x) + ", " + std::to_string(y) +
                                ") has a last step outside the saved time");
  }
  bool valid = probability(state.p_occ) && probability(state.p_occ_given_free) &&
               probability(state.p_free_given_occ) && std::isfinite(state.log_odds);
  for (const float s : state.em_stats) valid = valid && std::isfinite(s) && s >= 0.0f;
  const bool kinds = config_.learner == TransitionLearner::kKinds;
  if (valid && kinds) {
    // A kinds cell holds a probability distribution over (kind, state): a joint that does not
    // sum to 1 would make its next step's belief NaN.
    double total = 0.0;
    for (int k = 0; k < 2 * kKindCount; ++k) total += state.em_stats[k];
    valid = std::abs(total - 1.0) <= 1e-3;
  }
  if (!valid) {
    throw std::invalid_argument("restoreCell: cell (" + std::to_string(x) + ", " + std::to_string(y) +
                                ") has values out of range" +
                                (kinds ? " (its kind posterior must be >= 0 and sum to 1)" : ""));
  }
  if (!grid_.insideLimits(x, y)) {
    throw std::invalid_argument("restoreCell: cell (" + std::to_string(x) + ", " + std::to_string(y) +
                                ") is outside the map's limits");
  }
  CellBox box;
  box.include(x, y);
  grid_.reserve(box);
  CellGrid::Tile* tile = grid_.tileForWriting(x, y);
  const int i = CellGrid::offsetOf(x, y);
  tile->p_occ[i] = state.p_occ;
  tile->last_step[i] = state.last_step;
  tile->log_odds[i] = state.log_odds;
  tile->p_occ_given_free[i] = state.p_occ_given_free;
  tile->p_free_given_occ[i] = state.p_free_given_occ;
  if (kinds) {
    for (std::size_t k = 0; k < state.em_stats.size(); ++k) tile->em_stats[k][i] = state.em_stats[k];
  } else {
    // Online EM's eight statistics.
    TransitionStats stats;
    for (std::size_t k = 0; k < stats.s.size(); ++k) stats.s[k] = state.em_stats[k];
    storeStats(*tile, i, stats);
  }
  tile->observed_steps[i] = state.observed_steps;
  tile->last_hits[i] = state.last_hits;
  tile->last_misses[i] = state.last_misses;
  tile_versions_.bump(tile->tile_x, tile->tile_y);
  changed_cells_.include(x, y);
}

void Mapper::setCellTransitions(std::int32_t x, std::int32_t y, const TransitionParams& params) {
  ++settings_revision_;
  const std::string cell = "setCellTransitions: cell (" + std::to_string(x) + ", " + std::to_string(y) + ")";
  if (!params.isValid()) throw std::invalid_argument(cell + ": transition probabilities must be in [0, 1]");
  if (!grid_.insideLimits(x, y)) throw std::invalid_argument(cell + " is outside the map's limits");
  CellBox box;
  box.include(x, y);
  grid_.reserve(box);
  CellGrid::Tile* tile = grid_.tileForWriting(x, y);
  const int i = CellGrid::offsetOf(x, y);
  const std::int32_t last = tile->last_step[i];
  if (!config_.learn_transitions && last != kNeverObserved && last_applied_step_ && *last_applied_step_ > last) {
    // The steps since the cell's last update happened under the old transitions: carry the
    // belief over them first, so the new ones only act from now on.
    const TransitionParams old{tile->p_occ_given_free[i], tile->p_free_given_occ[i]};
    tile->p_occ[i] = static_cast<float>(predictOccupancy(tile->p_occ[i], old, *last_applied_step_ - last));
    tile->last_step[i] = static_cast<std::int32_t>(*last_applied_step_);
  }
  tile->p_occ_given_free[i] = static_cast<float>(params.p_occ_given_free);
  tile->p_free_given_occ[i] = static_cast<float>(params.p_free_given_occ);
  tile_versions_.bump(tile->tile_x, tile->tile_y);
  if (last != kNeverObserved) changed_cells_.include(x, y);
}

void Mapper::setSensorModel(double p_hit_given_occ, double p_hit_given_free) {
  ++settings_revision_;
  // Throws for a bad model.
  sensor_ = ObservationModel(p_hit_given_occ, p_hit_given_free, config_.sensor_model_mixed_step_probability);
  static_sensor_ = ObservationModel(p_hit_given_occ, p_hit_given_free);
  config_.p_hit_given_occ = p_hit_given_occ;
  config_.p_hit_given_free = p_hit_given_free;
  // With learn_sensor_model the new values are where learning starts again.
  sensor_stats_ = SensorModelStats{};
}

void Mapper::setViewSwitchProbability(double view_switch_probability) {
  ++settings_revision_;
  kinds_.setViewSwitchProbability(view_switch_probability);
  config_.kinds.view_switch_probability = view_switch_probability;
}

void Mapper::setMixedStepProbability(double mixed_step_probability) {
  ++settings_revision_;
  // Throws for a value outside [0, 0.5].
  sensor_ = ObservationModel(sensor_.pHitGivenOcc(), sensor_.pHitGivenFree(), mixed_step_probability);
  config_.sensor_model_mixed_step_probability = mixed_step_probability;
}

CellBox Mapper::takeChangedCells() {
  const CellBox changed = changed_cells_;
  changed_cells_ = CellBox{};
  return changed;
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
