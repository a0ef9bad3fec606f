#include "dynamic_occupancy_grid/core/pose/pose_filter.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

#include <Eigen/Dense>

#include "dynamic_occupancy_grid/core/common/parallel.h"
#include "dynamic_occupancy_grid/core/pose/resampling.h"
#include "dynamic_occupancy_grid/core/grid/scan_beams.h"

namespace dynamic_occupancy_grid {
namespace core {

namespace {

constexpr double kPi = 3.14159265358979323846;

void require(bool condition, const std::string& message) {
  if (!condition) throw std::invalid_argument("PoseFilterConfig: " + message);
}

bool finitePositive(double value) { return std::isfinite(value) && value > 0.0; }

/// scanEvidence's scratch grid (4 bytes a cell, per thread) spans the scan's box: at most
/// this many cells (2048 x 2048: 51 m of range at 0.05 m cells).
constexpr std::int64_t kMaxEvidenceBoxCells = std::int64_t{2048} * 2048;

using LaserPoint = PoseFilter::LaserPoint;

/// The ends of every `stride`-th beam with a return, in the laser's frame.
std::vector<LaserPoint> matchBeams(const Scan& scan, std::size_t stride) {
  std::vector<LaserPoint> beams;
  std::size_t with_return = 0;
  for (std::size_t i = 0; i < scan.ranges_m.size(); ++i) {
    const double range = scan.ranges_m[i];
    if (!(range >= scan.range_min_m && range < scan.range_max_m)) continue;
    if (with_return++ % stride != 0) continue;
    const double beam_angle = scan.angle_min_rad + static_cast<double>(i) * scan.angle_increment_rad;
    const double angle = scan.upside_down ? -beam_angle : beam_angle;
    beams.push_back(LaserPoint{range * std::cos(angle), range * std::sin(angle)});
  }
  return beams;
}

}  // namespace

void PoseFilterConfig::validate() const {
  require(particles >= 1, "particles must be >= 1");
  motion_noise.validate();
  require(finitePositive(update_distance_m), "update_distance_m must be finite and > 0");
  require(finitePositive(update_angle_rad), "update_angle_rad must be finite and > 0");
  require(resample_below >= 0.0 && resample_below <= 1.0, "resample_below must be in [0, 1]");
  require(finitePositive(resolution_m), "resolution_m must be finite and > 0");
  require(finitePositive(time_step_s), "time_step_s must be finite and > 0");
  ObservationModel(p_hit_given_occ, p_hit_given_free);  // throws for a bad sensor model
  require(unknown_p_occ > 0.0 && unknown_p_occ < 1.0, "unknown_p_occ must be in (0, 1)");
  require(std::isfinite(max_free_range_m) && max_free_range_m >= 0.0, "max_free_range_m must be finite and >= 0");
  require(finitePositive(max_range_m), "max_range_m must be finite and > 0");
  require(2.0 * max_range_m / resolution_m + 3.0 <= 2048.0,
          "max_range_m must be at most 1022 cells (51 m at 0.05 m cells): a scan's box is at most 2048 cells wide");
  require(match_beam_stride >= 1, "match_beam_stride must be >= 1");
  require(finitePositive(match_sigma_m), "match_sigma_m must be finite and > 0");
  require(finitePositive(match_linear_step_m), "match_linear_step_m must be finite and > 0");
  require(finitePositive(match_angular_step_rad), "match_angular_step_rad must be finite and > 0");
  require(match_max_iterations >= 0, "match_max_iterations must be >= 0");
  require(std::isfinite(match_min_score) && match_min_score >= 0.0, "match_min_score must be finite and >= 0");
  require(weight_beams >= 1, "weight_beams must be >= 1");
  require(finitePositive(weight_sigma_m), "weight_sigma_m must be finite and > 0");
  require(std::isfinite(weight_z_hit) && weight_z_hit >= 0.0, "weight_z_hit must be finite and >= 0");
  require(finitePositive(weight_z_rand), "weight_z_rand must be finite and > 0");
  require(finitePositive(weight_max_distance_m) && weight_max_distance_m / resolution_m <= 64.0,
          "weight_max_distance_m must be finite, > 0 and at most 64 cells");
  require(std::isfinite(guard_sigmas) && guard_sigmas >= 0.0, "guard_sigmas must be finite and >= 0");
  require(std::isfinite(guard_window_m) && guard_window_m >= 0.0, "guard_window_m must be finite and >= 0");
  require(std::isfinite(correction_min_gain), "correction_min_gain must be finite");
}

double nearestOccupiedDistance(const ParticleMap& map, const TransitionSource& transitions, double x_m,
                               double y_m, double resolution_m, double max_distance_m, std::int64_t step,
                               double unknown_p_occ) {
  ParticleMap::Reader reader(map);
  return resolution_m * nearestCellDistance(x_m / resolution_m, y_m / resolution_m, max_distance_m / resolution_m,
                                            [&](std::int32_t x, std::int32_t y) {
                                              return reader.lastStep(x, y) != kNeverObserved &&
                                                     reader.predicted(x, y, step, transitions, unknown_p_occ) > 0.5;
                                            });
}

double beamLogLikelihood(const PoseFilterConfig& config, double distance_m) {
  const double kernel = -0.5 / (config.weight_sigma_m * config.weight_sigma_m);
  return std::log(config.weight_z_hit * std::exp(kernel * distance_m * distance_m) + config.weight_z_rand);
}

std::vector<std::array<double, 2>> weightBeams(const Scan& scan, std::size_t count) {
  const std::vector<LaserPoint> all = matchBeams(scan, 1);
  if (all.size() <= count) return all;
  std::vector<LaserPoint> beams;
  beams.reserve(count);
  for (std::size_t k = 0; k < count; ++k) beams.push_back(all[(2 * k + 1) * all.size() / (2 * count)]);
  return beams;
}

bool guardAccepts(const TrajectoryNode& anchor, const Pose2D& pose, const Pose2D& odometry, double travelled_m,
                  double heading_variance, double translation_variance, double sigmas, double floor_m) {
  const Pose2D predicted = composePose(anchor.pose, relativePose(anchor.odometry, odometry));
  const double heading_var = std::max(0.0, heading_variance - anchor.heading_variance);
  const double distance = std::max(0.0, travelled_m - anchor.travelled_m);
  const double position_var = std::max(0.0, translation_variance - anchor.translation_variance) +
                              distance * distance * heading_var / 3.0 + floor_m * floor_m;
  const double turn = std::abs(std::remainder(pose.yaw_rad - predicted.yaw_rad, 2.0 * kPi));
  const double shift = std::hypot(pose.x_m - predicted.x_m, pose.y_m - predicted.y_m);
  return turn <= sigmas * std::sqrt(heading_var) + 1e-12 && shift <= sigmas * std::sqrt(position_var) + 1e-12;
}

std::vector<CellEvidence> scanEvidence(const Scan& scan, const Pose2D& laser_pose, double resolution_m,
                                       double max_free_range_m, double max_range_m) {
  Scan placed = scan;
  placed.laser_pose = laser_pose;
  if (const auto error = scanFieldsError(placed)) throw std::invalid_argument("scanEvidence: " + *error);
  BeamRules rules;
  rules.cells_per_m = 1.0 / resolution_m;
  rules.max_free_range_m = max_free_range_m;
  rules.max_beam_m = max_range_m;
  // As the Mapper's lattice does it (times the inverse), so that both trace the same cells.
  const double u0 = laser_pose.x_m * rules.cells_per_m;
  const double v0 = laser_pose.y_m * rules.cells_per_m;
  std::vector<BeamEnd> ends;
  BeamCounts counts;
  CellBox box;
  if (std::abs(u0) > kMaxLatticeCoordinate || std::abs(v0) > kMaxLatticeCoordinate ||
      beamEnds(placed, u0, v0, rules, ends, counts, box)) {
    throw std::invalid_argument("scanEvidence: a beam ends beyond the lattice");
  }
  // A scan observes a cell once, as the Mapper does: a hit if any beam ends there with a
  // return, a miss otherwise. Marks on a scratch grid over the scan's box (every beam's
  // cells lie in it) find each cell's first visit; the marks are cleared afterwards.
  const std::int64_t width = box.width();
  const std::int64_t cells = width * box.height();
  if (cells > kMaxEvidenceBoxCells) {
    throw std::invalid_argument("scanEvidence: the scan spans " + std::to_string(cells) +
                                " cells; max_range / resolution too large");
  }
  // By box index: 0 if the scan has not reached the cell yet, else 1 + its entry's index.
  thread_local std::vector<std::uint32_t> marks;
  if (marks.size() < static_cast<std::size_t>(cells)) marks.assign(static_cast<std::size_t>(cells), 0);
  std::vector<CellEvidence> evidence;
  const auto visit = [&](std::int32_t x, std::int32_t y, bool hit) {
    std::uint32_t& mark = marks[static_cast<std::size_t>((std::int64_t{y} - box.min_y) * width + (x - box.min_x))];
    if (mark == 0) {
      evidence.push_back(hit ? CellEvidence{x, y, 1, 0} : CellEvidence{x, y, 0, 1});
      mark = static_cast<std::uint32_t>(evidence.size());
    } else if (hit) {
      evidence[mark - 1] = CellEvidence{x, y, 1, 0};  // the hit wins over a miss
    }
  };
  for (const BeamEnd& beam : ends) {
    const CellXY end = traverseSegment(u0, v0, beam.u1, beam.v1, [&](std::int32_t x, std::int32_t y) { visit(x, y, false); });
    visit(end.x, end.y, beam.hit);
  }
  for (const CellEvidence& cell : evidence) {
    marks[static_cast<std::size_t>((std::int64_t{cell.y} - box.min_y) * width + (cell.x - box.min_x))] = 0;
  }
  return evidence;
}

PoseFilter::PoseFilter(const PoseFilterConfig& config, std::shared_ptr<const TransitionSource> transitions)
    : config_(config),
      transitions_(std::move(transitions)),
      sensor_(config.p_hit_given_occ, config.p_hit_given_free),
      clock_(config.time_step_s),
      rng_(config.seed) {
  config_.validate();
  if (!transitions_) throw std::invalid_argument("PoseFilter: no transition source");
  particles_.resize(config_.particles);
}

namespace {

/// gmapping's kind of scan-matching score: per beam, exp(-d^2 / 2 sigma^2) of the distance d
/// from its end to the nearest cell centre of the 3 x 3 around it that the map, predicted to
/// `step`, holds occupied (p > 0.5); 0 if none.
double matchScore(const ParticleMap& map, const TransitionSource& transitions, const PoseFilterConfig& config,
                  const std::vector<LaserPoint>& beams, const Pose2D& pose, std::int64_t step) {
  const double c = std::cos(pose.yaw_rad);
  const double s = std::sin(pose.yaw_rad);
  const double inverse_resolution = 1.0 / config.resolution_m;
  const double cells_per_sigma = config.match_sigma_m * inverse_resolution;
  const double kernel = -0.5 / (cells_per_sigma * cells_per_sigma);  // d in cells
  double score = 0.0;
  ParticleMap::Reader reader(map);
  for (const LaserPoint& beam : beams) {
    const double u = (pose.x_m + c * beam[0] - s * beam[1]) * inverse_resolution;
    const double v = (pose.y_m + s * beam[0] + c * beam[1]) * inverse_resolution;
    const auto cx = static_cast<std::int32_t>(std::floor(u));
    const auto cy = static_cast<std::int32_t>(std::floor(v));
    double best = 0.0;
    for (std::int32_t dy = -1; dy <= 1; ++dy) {
      for (std::int32_t dx = -1; dx <= 1; ++dx) {
        if (reader.predicted(cx + dx, cy + dy, step, transitions, config.unknown_p_occ) <= 0.5) continue;
        const double du = u - (cx + dx + 0.5);
        const double dv = v - (cy + dy + 0.5);
        best = std::max(best, std::exp(kernel * (du * du + dv * dv)));
      }
    }
    score += best;
  }
  return score;
}

/// Whether the map has observed a cell of the 3 x 3 around the end of `beam` from `pose`.
bool endInMappedPlace(ParticleMap::Reader& map, const PoseFilterConfig& config, const LaserPoint& beam,
                      const Pose2D& pose) {
  const double c = std::cos(pose.yaw_rad);
  const double s = std::sin(pose.yaw_rad);
  const auto cx = static_cast<std::int32_t>(std::floor((pose.x_m + c * beam[0] - s * beam[1]) / config.resolution_m));
  const auto cy = static_cast<std::int32_t>(std::floor((pose.y_m + s * beam[0] + c * beam[1]) / config.resolution_m));
  for (std::int32_t dy = -1; dy <= 1; ++dy) {
    for (std::int32_t dx = -1; dx <= 1; ++dx) {
      if (map.lastStep(cx + dx, cy + dy) != kNeverObserved) return true;
    }
  }
  return false;
}

}  // namespace

double fieldLogLikelihood(const ParticleMap& map, const TransitionSource& transitions, const PoseFilterConfig& config,
                          const std::vector<std::array<double, 2>>& beams, const Pose2D& pose, std::int64_t step,
                          const Pose2D* compared_with) {
  ParticleMap::Reader reader(map);
  const double c = std::cos(pose.yaw_rad);
  const double s = std::sin(pose.yaw_rad);
  double sum = 0.0;
  for (const LaserPoint& beam : beams) {
    double d = 0.0;
    if (endInMappedPlace(reader, config, beam, pose) &&
        (compared_with == nullptr || endInMappedPlace(reader, config, beam, *compared_with))) {
      d = nearestOccupiedDistance(map, transitions, pose.x_m + c * beam[0] - s * beam[1],
                                  pose.y_m + s * beam[0] + c * beam[1], config.resolution_m,
                                  config.weight_max_distance_m, step, config.unknown_p_occ);
    }
    sum += beamLogLikelihood(config, d);
  }
  return sum;
}

Pose2D PoseFilter::matchPose(const Particle& particle, const std::vector<LaserPoint>& match_beams, const Pose2D& start,
                             std::int64_t step) const {
  // Only the beams that end where the map has been, seen from the proposal's pose, and the
  // same beams at every pose tried: a score over whichever beams happen to end in mapped
  // places would pull the pose back to where the map is (along a corridor, back towards
  // where the robot came from).
  std::vector<LaserPoint> beams;
  ParticleMap::Reader reader(particle.map);
  for (const LaserPoint& beam : match_beams) {
    if (endInMappedPlace(reader, config_, beam, start)) beams.push_back(beam);
  }
  if (beams.empty()) return start;
  Pose2D pose = start;
  double score = matchScore(particle.map, *transitions_, config_, beams, pose, step);
  double linear = config_.match_linear_step_m;
  double angular = config_.match_angular_step_rad;
  int refinements = 0;
  for (int iteration = 0; iteration < config_.match_max_iterations; ++iteration) {
    Pose2D best_move = pose;
    double best_score = score;
    const Pose2D moves[6] = {{pose.x_m + linear, pose.y_m, pose.yaw_rad}, {pose.x_m - linear, pose.y_m, pose.yaw_rad},
                             {pose.x_m, pose.y_m + linear, pose.yaw_rad}, {pose.x_m, pose.y_m - linear, pose.yaw_rad},
                             {pose.x_m, pose.y_m, pose.yaw_rad + angular}, {pose.x_m, pose.y_m, pose.yaw_rad - angular}};
    for (const Pose2D& move : moves) {
      const double move_score = matchScore(particle.map, *transitions_, config_, beams, move, step);
      if (move_score > best_score) {
        best_score = move_score;
        best_move = move;
      }
    }
    if (best_score > score) {
      pose = best_move;
      score = best_score;
    } else {
      if (++refinements > 4) break;
      linear *= 0.5;
      angular *= 0.5;
    }
  }
  if (score < config_.match_min_score * static_cast<double>(beams.size())) return start;
  pose.yaw_rad = std::remainder(pose.yaw_rad, 2.0 * kPi);
  return pose;
}

bool PoseFilter::updateParticle(Particle& particle, const Scan& scan, const std::vector<LaserPoint>& match_beams,
                                const std::vector<LaserPoint>& weight_beams, const OdometryMotion& motion,
                                const std::array<double, 3>& normals, std::int64_t step) const {
  Pose2D pose = applyMotion(particle.pose, perturbMotion(motion, config_.motion_noise, normals));
  if (config_.scan_matching) pose = matchPose(particle, match_beams, pose, step);
  // The motion model's variances of this motion (as perturbMotion's), accumulated along the
  // lineage for the guard.
  const TrajectoryNode& last = *particle.trajectory;
  const OdometryNoise& noise = config_.motion_noise;
  const auto turn_size = [](double rot) {
    const double folded = std::abs(rot);
    return std::min(folded, kPi - folded);
  };
  const double r1 = turn_size(motion.rot1_rad);
  const double r2 = turn_size(motion.rot2_rad);
  const double t2 = motion.trans_m * motion.trans_m;
  const double heading_variance = last.heading_variance + noise.rot_from_rot * (r1 * r1 + r2 * r2) +
                                  2.0 * noise.rot_from_trans * t2;
  const double translation_variance =
      last.translation_variance + noise.trans_from_trans * t2 + noise.trans_from_rot * (r1 * r1 + r2 * r2);
  const double travelled = last.travelled_m + motion.trans_m;
  bool refused = false;
  if (config_.guard_sigmas > 0.0 || config_.correction_test) {
    // Odometry's increment from the particle's last pose: what the particle falls back to.
    Pose2D odometry_pose = applyMotion(particle.pose, motion);
    odometry_pose.yaw_rad = std::remainder(odometry_pose.yaw_rad, 2.0 * kPi);
    // The guard's anchor: the lineage's state guard_window_m of travel ago (or its first).
    const TrajectoryNode* anchor = &last;
    while (anchor->parent && travelled - anchor->travelled_m < config_.guard_window_m) anchor = anchor->parent.get();
    // The correction test's field: the weight's with the matcher's kernel.
    PoseFilterConfig test_config = config_;
    test_config.weight_sigma_m = config_.match_sigma_m;
    const auto test_log_likelihood = [&](const Pose2D& at, const Pose2D& compared_with) {
      return fieldLogLikelihood(particle.map, *transitions_, test_config, weight_beams, at, step, &compared_with);
    };
    // Whether `candidate` is refused: by the guard, or by the correction test.
    const auto refuses = [&](const Pose2D& candidate) {
      if (config_.guard_sigmas > 0.0 &&
          !guardAccepts(*anchor, candidate, scan.laser_pose, travelled, heading_variance, translation_variance,
                        config_.guard_sigmas, config_.resolution_m)) {
        return true;
      }
      if (!config_.correction_test) return false;
      // The pose against odometry's increment: the scan's log-likelihood ratio minus the
      // motion model's (a Gaussian with this update's heading and position variances) must
      // reach correction_min_gain.
      // On the same beams: a beam whose end either pose puts where the map has not been
      // (behind a wall, say) counts as explained at both, so that no pose gains beams by
      // putting them there (docs/pose_correction_real.md, "Comparing on the same beams").
      const double scan_gain =
          test_log_likelihood(candidate, odometry_pose) - test_log_likelihood(odometry_pose, candidate);
      const double step_heading_var = heading_variance - last.heading_variance;
      const double step_position_var =
          translation_variance - last.translation_variance + t2 * step_heading_var / 3.0;
      const double turn = std::remainder(candidate.yaw_rad - odometry_pose.yaw_rad, 2.0 * kPi);
      const double shift2 = (candidate.x_m - odometry_pose.x_m) * (candidate.x_m - odometry_pose.x_m) +
                            (candidate.y_m - odometry_pose.y_m) * (candidate.y_m - odometry_pose.y_m);
      const double prior = -0.5 * (turn * turn / std::max(step_heading_var, 1e-300) +
                                   shift2 / std::max(step_position_var, 1e-300));
      return scan_gain + prior < config_.correction_min_gain;
    };
    const auto same = [](const Pose2D& a, const Pose2D& b) {
      return std::abs(a.x_m - b.x_m) <= 1e-9 && std::abs(a.y_m - b.y_m) <= 1e-9 &&
             std::abs(std::remainder(a.yaw_rad - b.yaw_rad, 2.0 * kPi)) <= 1e-9;
    };
    if (refuses(pose)) {
      // The sample keeps the motion model's noise where the scan cannot see it (along a
      // corridor, say), and the prior charges for it, so a correction the scan supports can
      // be refused with it. The second candidate: odometry's increment matched, which leaves
      // odometry's pose where the scan says nothing (docs/pose_correction_real.md, "Matching
      // odometry's increment").
      Pose2D taken = odometry_pose;
      if (config_.scan_matching) {
        const Pose2D rematched = matchPose(particle, match_beams, odometry_pose, step);
        if (!same(rematched, odometry_pose) && !refuses(rematched)) taken = rematched;
      }
      refused = !same(pose, odometry_pose) && same(taken, odometry_pose);
      pose = taken;
    }
  }
  // The weight: amcl's likelihood field over the subsampled beams.
  particle.log_weight += fieldLogLikelihood(particle.map, *transitions_, config_, weight_beams, pose, step);
  particle.pose = pose;
  auto node = std::make_shared<TrajectoryNode>(TrajectoryNode{scan.stamp_s, pose, particle.trajectory});
  node->odometry = scan.laser_pose;
  node->travelled_m = travelled;
  node->heading_variance = heading_variance;
  node->translation_variance = translation_variance;
  particle.trajectory = std::move(node);
  return refused;
}

void PoseFilter::mapEvidence(ParticleMap& map, const std::vector<CellEvidence>& evidence, std::int64_t step) const {
  ParticleMap::Writer writer(map);
  for (const CellEvidence& cell : evidence) {
    writer.update(cell.x, cell.y, step, sensor_.logLikelihoodRatio(cell.hits, cell.misses), *transitions_,
                  config_.unknown_p_occ);
  }
}

void PoseFilter::startStepsAt(double origin_s) {
  if (last_odometry_) throw std::logic_error("PoseFilter::startStepsAt: the filter has started");
  steps_origin_s_ = origin_s;
}

PoseUpdate PoseFilter::integrate(const Scan& scan) {
  if (const auto error = scanFieldsError(scan)) throw std::invalid_argument("PoseFilter: " + *error);
  PoseUpdate result;
  const Pose2D& odometry = scan.laser_pose;
  if (!last_odometry_) {
    // Nothing changes before the scan is known to be usable (a refused first scan leaves the
    // filter as it was).
    StepClock clock(config_.time_step_s);
    clock.startAt(steps_origin_s_.value_or(scan.stamp_s));
    if (!(scan.stamp_s >= *clock.origin() && clock.stepOf(scan.stamp_s) == 0)) {
      throw std::invalid_argument("PoseFilter: the first scan's stamp " + std::to_string(scan.stamp_s) +
                                  " is not in step 0, which starts at " + std::to_string(*clock.origin()));
    }
    Particle first;
    first.pose = odometry;
    const std::vector<CellEvidence> evidence =
        scanEvidence(scan, odometry, config_.resolution_m, config_.max_free_range_m, config_.max_range_m);
    clock_ = clock;
    mapEvidence(first.map, evidence, 0);
    auto root = std::make_shared<TrajectoryNode>(TrajectoryNode{scan.stamp_s, odometry, nullptr});
    root->odometry = odometry;
    first.trajectory = std::move(root);
    std::fill(particles_.begin(), particles_.end(), first);  // every map shares the first's tiles
    last_odometry_ = odometry;
    last_step_ = 0;
    ++updates_;
    result.updated = true;
    result.effective_sample_size = static_cast<double>(particles_.size());
    result.map_bytes = ParticleMap::distinctTileBytes({&particles_.front().map});
    return result;
  }
  const std::int64_t step = clock_.stepOf(scan.stamp_s);
  if (step < last_step_) {
    throw std::invalid_argument("PoseFilter: the scan's stamp is in step " + std::to_string(step) +
                                ", before the last update's step " + std::to_string(last_step_));
  }
  const OdometryMotion motion = odometryMotion(*last_odometry_, odometry);
  const double turned = std::abs(std::remainder(odometry.yaw_rad - last_odometry_->yaw_rad, 2.0 * kPi));
  if (motion.trans_m < config_.update_distance_m && turned < config_.update_angle_rad) return result;

  const auto started_at = std::chrono::steady_clock::now();
  // The noise of every particle drawn here, in particle order: results do not depend on the
  // threads.
  std::normal_distribution<double> normal;
  std::vector<std::array<double, 3>> normals(particles_.size());
  for (auto& draw : normals) {
    for (double& value : draw) value = normal(rng_);
  }
  const std::vector<LaserPoint> match_beams = matchBeams(scan, config_.match_beam_stride);  // the same for all
  const std::vector<LaserPoint> weight_beams = weightBeams(scan, config_.weight_beams);
  std::vector<char> refused(particles_.size(), 0);
  runRepetitions(particles_.size(), config_.threads,
                 [&](std::size_t i) {
                   refused[i] = updateParticle(particles_[i], scan, match_beams, weight_beams, motion, normals[i], step);
                 },
                 nullptr);
  for (const char r : refused) guard_refusals_ += r != 0 ? 1 : 0;
  last_odometry_ = odometry;
  last_step_ = step;
  ++updates_;
  result.updated = true;
  result.effective_sample_size = effectiveSampleSize();
  effective_sample_sizes_.push_back(result.effective_sample_size);
  std::vector<std::size_t> ancestors(particles_.size());
  for (std::size_t i = 0; i < ancestors.size(); ++i) ancestors[i] = i;
  if (result.effective_sample_size < config_.resample_below * static_cast<double>(particles_.size())) {
    ancestors = resample();
    result.resampled = true;
  }
  mapScan(scan, ancestors, step);
  std::vector<const ParticleMap*> maps;
  for (const Particle& particle : particles_) maps.push_back(&particle.map);
  result.map_bytes = ParticleMap::distinctTileBytes(maps);
  update_seconds_ += std::chrono::duration<double>(std::chrono::steady_clock::now() - started_at).count();
  return result;
}

void PoseFilter::mapScan(const Scan& scan, const std::vector<std::size_t>& ancestors, std::int64_t step) {
  // The first copy of each ancestor maps the scan; the others let go of their map first (so
  // that the tiles it writes are shared with fewer maps, and copied only if another
  // ancestor's map still holds them), then take the updated one.
  std::vector<std::size_t> writers;
  std::vector<std::size_t> writer_of(particles_.size());
  for (std::size_t i = 0; i < particles_.size(); ++i) {
    std::size_t j = 0;
    while (j < writers.size() && ancestors[writers[j]] != ancestors[i]) ++j;
    if (j == writers.size()) {
      writers.push_back(i);
    } else {
      particles_[i].map = ParticleMap{};
    }
    writer_of[i] = writers[j];
  }
  runRepetitions(writers.size(), config_.threads,
                 [&](std::size_t k) {
                   Particle& particle = particles_[writers[k]];
                   mapEvidence(particle.map,
                               scanEvidence(scan, particle.pose, config_.resolution_m, config_.max_free_range_m,
                                            config_.max_range_m),
                               step);
                 },
                 nullptr);
  for (std::size_t i = 0; i < particles_.size(); ++i) {
    if (writer_of[i] != i) particles_[i].map = particles_[writer_of[i]].map;
  }
}

std::vector<std::size_t> PoseFilter::resample() {
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  const std::vector<std::size_t> copies = residualResample(weights(), particles_.size(), [&] { return uniform(rng_); });
  std::vector<Particle> next;
  std::vector<std::size_t> ancestors;
  next.reserve(particles_.size());
  ancestors.reserve(particles_.size());
  // The weights are equal afterwards, and bestIndex() takes the first of equals: the copies
  // of the best particle (which has floor(N w) >= 1 of them, its w being >= 1/N) come first.
  const std::size_t best = bestIndex();
  std::vector<std::size_t> order{best};
  for (std::size_t i = 0; i < particles_.size(); ++i) {
    if (i != best) order.push_back(i);
  }
  for (const std::size_t i : order) {
    for (std::size_t k = 0; k < copies[i]; ++k) {
      next.push_back(particles_[i]);  // the map's tiles are shared, not copied
      next.back().log_weight = 0.0;
      ancestors.push_back(i);
    }
  }
  particles_ = std::move(next);
  ++resamplings_;
  return ancestors;
}

std::vector<double> PoseFilter::weights() const {
  std::vector<double> log_weights;
  log_weights.reserve(particles_.size());
  for (const Particle& particle : particles_) log_weights.push_back(particle.log_weight);
  return normalisedWeights(log_weights);
}

double PoseFilter::effectiveSampleSize() const { return core::effectiveSampleSize(weights()); }

std::size_t PoseFilter::bestIndex() const {
  if (!started()) throw std::logic_error("PoseFilter::bestIndex: no scan yet");
  std::size_t best = 0;
  for (std::size_t i = 1; i < particles_.size(); ++i) {
    if (particles_[i].log_weight > particles_[best].log_weight) best = i;
  }
  return best;
}

double PoseFilter::poseEntropy() const {
  const std::vector<double> w = weights();
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  double sin_sum = 0.0;
  double cos_sum = 0.0;
  for (std::size_t i = 0; i < particles_.size(); ++i) {
    mean.x() += w[i] * particles_[i].pose.x_m;
    mean.y() += w[i] * particles_[i].pose.y_m;
    sin_sum += w[i] * std::sin(particles_[i].pose.yaw_rad);
    cos_sum += w[i] * std::cos(particles_[i].pose.yaw_rad);
  }
  mean.z() = std::atan2(sin_sum, cos_sum);
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity() * 1e-12;
  for (std::size_t i = 0; i < particles_.size(); ++i) {
    const Eigen::Vector3d d(particles_[i].pose.x_m - mean.x(), particles_[i].pose.y_m - mean.y(),
                            std::remainder(particles_[i].pose.yaw_rad - mean.z(), 2.0 * kPi));
    covariance += w[i] * d * d.transpose();
  }
  return 0.5 * std::log(std::pow(2.0 * kPi * std::exp(1.0), 3) * covariance.determinant());
}

Pose2D PoseFilter::mapToOdometry() const {
  if (!last_odometry_) throw std::logic_error("PoseFilter::mapToOdometry: no scan yet");
  Pose2D correction = composePose(best().pose, relativePose(*last_odometry_, Pose2D{}));
  correction.yaw_rad = std::remainder(correction.yaw_rad, 2.0 * kPi);
  return correction;
}

std::vector<TrajectoryNode> PoseFilter::bestTrajectory() const {
  std::vector<TrajectoryNode> trajectory;
  for (const TrajectoryNode* node = best().trajectory.get(); node != nullptr; node = node->parent.get()) {
    trajectory.push_back(TrajectoryNode{node->stamp_s, node->pose, nullptr});
  }
  std::reverse(trajectory.begin(), trajectory.end());
  return trajectory;
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
