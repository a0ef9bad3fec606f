#include "dynamic_occupancy_grid/core/pose_filter.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include <Eigen/Dense>

#include "dynamic_occupancy_grid/core/parallel.h"
#include "dynamic_occupancy_grid/core/resampling.h"
#include "dynamic_occupancy_grid/core/scan_beams.h"

namespace dynamic_occupancy_grid {
namespace core {

namespace {

constexpr double kPi = 3.14159265358979323846;

void require(bool condition, const std::string& message) {
  if (!condition) throw std::invalid_argument("PoseFilterConfig: " + message);
}

bool finitePositive(double value) { return std::isfinite(value) && value > 0.0; }

/// A beam with a return, in the laser's frame: its end at `range` along `angle`.
struct BeamPoint {
  double x_m;
  double y_m;
};

std::vector<BeamPoint> matchBeams(const Scan& scan, std::size_t stride) {
  std::vector<BeamPoint> beams;
  std::size_t with_return = 0;
  for (std::size_t i = 0; i < scan.ranges_m.size(); ++i) {
    const double range = scan.ranges_m[i];
    if (!(range >= scan.range_min_m && range < scan.range_max_m)) continue;
    if (with_return++ % stride != 0) continue;
    const double beam_angle = scan.angle_min_rad + static_cast<double>(i) * scan.angle_increment_rad;
    const double angle = scan.upside_down ? -beam_angle : beam_angle;
    beams.push_back(BeamPoint{range * std::cos(angle), range * std::sin(angle)});
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
  require(match_beam_stride >= 1, "match_beam_stride must be >= 1");
  require(finitePositive(match_sigma_m), "match_sigma_m must be finite and > 0");
  require(finitePositive(match_linear_step_m), "match_linear_step_m must be finite and > 0");
  require(finitePositive(match_angular_step_rad), "match_angular_step_rad must be finite and > 0");
  require(match_max_iterations >= 0, "match_max_iterations must be >= 0");
  require(std::isfinite(match_min_score) && match_min_score >= 0.0, "match_min_score must be finite and >= 0");
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
  // One entry per beam cell: the cell and whether the beam ends there with a return;
  // sorted, equal cells are adjacent. A scan observes a cell once, as the Mapper does: a hit
  // if any beam ends there with a return, a miss otherwise. Lattice coordinates
  // are within +-kMaxLatticeCoordinate < 2^30: offset by 2^30, each fits in 31 bits.
  constexpr std::int64_t kOffset = std::int64_t{1} << 30;
  static_assert(kMaxLatticeCoordinate < static_cast<double>(kOffset), "cell keys need coordinates below 2^30");
  std::vector<std::uint64_t> marks;
  const auto mark = [&marks](std::int32_t x, std::int32_t y, bool hit) {
    marks.push_back((static_cast<std::uint64_t>(x + kOffset) << 32) | (static_cast<std::uint64_t>(y + kOffset) << 1) |
                    (hit ? 1U : 0U));
  };
  for (const BeamEnd& beam : ends) {
    const CellXY end = traverseSegment(u0, v0, beam.u1, beam.v1, [&](std::int32_t x, std::int32_t y) { mark(x, y, false); });
    mark(end.x, end.y, beam.hit);
  }
  std::sort(marks.begin(), marks.end());
  std::vector<CellEvidence> evidence;
  for (const std::uint64_t entry : marks) {
    const auto x = static_cast<std::int32_t>(static_cast<std::int64_t>(entry >> 32) - kOffset);
    const auto y = static_cast<std::int32_t>(static_cast<std::int64_t>((entry >> 1) & 0x7fffffffU) - kOffset);
    if (evidence.empty() || evidence.back().x != x || evidence.back().y != y) evidence.push_back(CellEvidence{x, y, 0, 1});
    if (entry & 1U) evidence.back() = CellEvidence{x, y, 1, 0};
  }
  return evidence;
}

double cellEvidenceLogLikelihood(const CellEvidence& evidence, double q, const ObservationModel& sensor) {
  // log[q p(z|occ) + (1 - q) p(z|free)] = log p(z|free) + log(q e^llr + (1 - q)), the
  // last as a log-sum-exp (q = 0 or 1 and ratios of hundreds included).
  const double log_free = evidence.hits * std::log(sensor.pHitGivenFree()) +
                          evidence.misses * std::log1p(-sensor.pHitGivenFree());
  const double occupied = std::log(q) + sensor.logLikelihoodRatio(evidence.hits, evidence.misses);
  const double free = std::log1p(-q);
  const double top = std::max(occupied, free);
  return log_free + top + std::log1p(std::exp(std::min(occupied, free) - top));
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

double PoseFilter::matchScore(const Particle& particle, const Scan& scan, const Pose2D& pose, std::int64_t step,
                              std::size_t* beam_count) const {
  const std::vector<BeamPoint> beams = matchBeams(scan, config_.match_beam_stride);
  if (beam_count != nullptr) *beam_count = beams.size();
  const double c = std::cos(pose.yaw_rad);
  const double s = std::sin(pose.yaw_rad);
  const double inverse_resolution = 1.0 / config_.resolution_m;
  // exp(-d^2 / 2 sigma^2) with d in cells.
  const double cells_per_sigma = config_.match_sigma_m * inverse_resolution;
  const double kernel = -0.5 / (cells_per_sigma * cells_per_sigma);
  double score = 0.0;
  for (const BeamPoint& beam : beams) {
    const double u = (pose.x_m + c * beam.x_m - s * beam.y_m) * inverse_resolution;
    const double v = (pose.y_m + s * beam.x_m + c * beam.y_m) * inverse_resolution;
    const auto cx = static_cast<std::int32_t>(std::floor(u));
    const auto cy = static_cast<std::int32_t>(std::floor(v));
    double best = 0.0;
    for (std::int32_t dy = -1; dy <= 1; ++dy) {
      for (std::int32_t dx = -1; dx <= 1; ++dx) {
        const double q = particle.map.predicted(cx + dx, cy + dy, step, *transitions_, config_.unknown_p_occ);
        if (q <= 0.5) continue;
        const double du = u - (cx + dx + 0.5);
        const double dv = v - (cy + dy + 0.5);
        best = std::max(best, std::exp(kernel * (du * du + dv * dv)));
      }
    }
    score += best;
  }
  return score;
}

Pose2D PoseFilter::matchPose(const Particle& particle, const Scan& scan, const Pose2D& start, std::int64_t step) const {
  std::size_t beams = 0;
  Pose2D pose = start;
  double score = matchScore(particle, scan, pose, step, &beams);
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
      const double move_score = matchScore(particle, scan, move, step, nullptr);
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
  if (beams == 0 || score < config_.match_min_score * static_cast<double>(beams)) return start;
  pose.yaw_rad = std::remainder(pose.yaw_rad, 2.0 * kPi);
  return pose;
}

void PoseFilter::updateParticle(Particle& particle, const Scan& scan, const OdometryMotion& motion,
                                const std::array<double, 3>& normals, std::int64_t step) const {
  Pose2D pose = applyMotion(particle.pose, perturbMotion(motion, config_.motion_noise, normals));
  if (config_.scan_matching) pose = matchPose(particle, scan, pose, step);
  const std::vector<CellEvidence> evidence =
      scanEvidence(scan, pose, config_.resolution_m, config_.max_free_range_m, config_.max_range_m);
  double log_likelihood = 0.0;
  for (const CellEvidence& cell : evidence) {
    const double q = particle.map.predicted(cell.x, cell.y, step, *transitions_, config_.unknown_p_occ);
    log_likelihood += cellEvidenceLogLikelihood(cell, q, sensor_);
  }
  for (const CellEvidence& cell : evidence) {
    particle.map.update(cell.x, cell.y, step, sensor_.logLikelihoodRatio(cell.hits, cell.misses), *transitions_,
                        config_.unknown_p_occ);
  }
  particle.log_weight += log_likelihood;
  particle.pose = pose;
  particle.trajectory = std::make_shared<const TrajectoryNode>(TrajectoryNode{scan.stamp_s, pose, particle.trajectory});
}

PoseUpdate PoseFilter::integrate(const Scan& scan) {
  if (const auto error = scanFieldsError(scan)) throw std::invalid_argument("PoseFilter: " + *error);
  PoseUpdate result;
  const Pose2D& odometry = scan.laser_pose;
  if (!last_odometry_) {
    clock_.startAt(scan.stamp_s);
    Particle first;
    first.pose = odometry;
    const std::vector<CellEvidence> evidence =
        scanEvidence(scan, odometry, config_.resolution_m, config_.max_free_range_m, config_.max_range_m);
    for (const CellEvidence& cell : evidence) {
      first.map.update(cell.x, cell.y, 0, sensor_.logLikelihoodRatio(cell.hits, cell.misses), *transitions_,
                       config_.unknown_p_occ);
    }
    first.trajectory = std::make_shared<const TrajectoryNode>(TrajectoryNode{scan.stamp_s, odometry, nullptr});
    std::fill(particles_.begin(), particles_.end(), first);  // every map shares the first's tiles
    last_odometry_ = odometry;
    last_step_ = 0;
    ++updates_;
    result.updated = true;
    result.effective_sample_size = static_cast<double>(particles_.size());
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

  // The noise of every particle drawn here, in particle order: results do not depend on the
  // threads.
  std::normal_distribution<double> normal;
  std::vector<std::array<double, 3>> normals(particles_.size());
  for (auto& draw : normals) {
    for (double& value : draw) value = normal(rng_);
  }
  runRepetitions(particles_.size(), config_.threads,
                 [&](std::size_t i) { updateParticle(particles_[i], scan, motion, normals[i], step); }, nullptr);
  last_odometry_ = odometry;
  last_step_ = step;
  ++updates_;
  result.updated = true;
  result.effective_sample_size = effectiveSampleSize();
  if (result.effective_sample_size < config_.resample_below * static_cast<double>(particles_.size())) {
    resample();
    result.resampled = true;
  }
  return result;
}

void PoseFilter::resample() {
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  const std::vector<std::size_t> copies = residualResample(weights(), particles_.size(), [&] { return uniform(rng_); });
  std::vector<Particle> next;
  next.reserve(particles_.size());
  for (std::size_t i = 0; i < particles_.size(); ++i) {
    for (std::size_t k = 0; k < copies[i]; ++k) {
      next.push_back(particles_[i]);  // the map's tiles are shared, not copied
      next.back().log_weight = 0.0;
    }
  }
  particles_ = std::move(next);
  ++resamplings_;
}

std::vector<double> PoseFilter::weights() const {
  double top = -std::numeric_limits<double>::infinity();
  for (const Particle& particle : particles_) top = std::max(top, particle.log_weight);
  std::vector<double> weights(particles_.size());
  double total = 0.0;
  for (std::size_t i = 0; i < particles_.size(); ++i) {
    weights[i] = std::exp(particles_[i].log_weight - top);
    total += weights[i];
  }
  for (double& w : weights) w /= total;
  return weights;
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
