#pragma once
// Mapping under pose uncertainty: a Rao-Blackwellised particle filter whose particles
// sample the laser's trajectory and carry, each, the map given that trajectory as cell
// HMMs (Murphy, "Bayesian map learning in dynamic environments", NIPS 1999, §4; the map
// per particle as in gmapping, Grisetti et al. 2007).
//
// One update, once odometry has moved update_distance_m or update_angle_rad since the last:
//   1. proposal: each particle's pose moved by the odometry's motion read with the motion
//      model's noise (motion_model.h), then refined by scan matching against the
//      particle's map *predicted* to the scan's step (a hill climb of gmapping's kind on the
//      beam end points' distance to predicted-occupied cells);
//      The pose is refused when its correction of odometry is more than the motion model
//      allows over the last guard_window_m of travel (guardAccepts), or when the scan does
//      not support it (its likelihood, scored with the matcher's kernel, is not
//      correction_min_gain nats above odometry's increment's). A refused sample is followed
//      by a second candidate, odometry's increment from the particle's last pose matched
//      (the sample's noise where the scan cannot see it, along a corridor, costs it the test
//      though its heading is right), taken if neither test refuses it; otherwise odometry's
//      increment itself;
//   2. weight: times the scan's likelihood under the particle's predicted map, amcl's
//      likelihood field: weight_beams beams evenly subsampled, each end's distance d to the
//      nearest cell the map predicts occupied scored z_hit exp(-d^2 / 2 sigma^2) + z_rand.
//      (The exact incremental weight, a product over the 2 500-6 000 cells a real scan
//      reaches, ranked particles 2-5 cm apart by 15 nats and resampled at every update to
//      one lineage: docs/pose_correction_real.md.) A beam ending where the particle's map
//      has not been counts as explained (no pull towards mapped places: along a corridor
//      that pull shrank every leg);
//   3. resampling (Liu's residual resampling) when N_eff = 1 / sum w^2 falls below
//      resample_below * N. Maps are copied by their tile pointers (particle_map.h);
//   4. map: each cell the scan reaches takes one filter step with its evidence from the
//      particle's pose. After resampling, the copies of one particle have one pose and one
//      map: that map is updated once and shared (gmapping also maps after resampling), so
//      only the distinct survivors' maps copy the tiles the scan writes.
// A door the model predicts open (or a parked car predicted gone) is no evidence against a
// particle that sees it open: that is where a dynamic map keeps particles where a static
// one pulls them away.
//
// ROS-free: standard library only.

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <random>
#include <vector>

#include "dynamic_occupancy_grid/core/pose/motion_model.h"
#include "dynamic_occupancy_grid/core/pose/particle_map.h"
#include "dynamic_occupancy_grid/core/grid/scan.h"
#include "dynamic_occupancy_grid/core/grid/step_clock.h"

namespace dynamic_occupancy_grid {
namespace core {

struct PoseFilterConfig {
  std::size_t particles = 30;
  /// The odometry's noise (amcl's odom_alpha1..4) for the proposal.
  OdometryNoise motion_noise{0.05, 0.05, 0.05, 0.05};
  /// The weight: a likelihood field (amcl's likelihood_field model) over at most this many
  /// beams with a return, evenly subsampled; each beam end's distance d to the nearest
  /// cell its particle's map predicts occupied (p > 0.5) gives
  /// p = weight_z_hit exp(-d^2 / 2 weight_sigma_m^2) + weight_z_rand. A beam ending where
  /// the particle's map has not been (no observed cell in the 3 x 3 around its end) counts
  /// as explained (d = 0): no pull towards mapped places.
  std::size_t weight_beams = 60;
  double weight_sigma_m = 0.15;
  double weight_z_hit = 0.95;
  double weight_z_rand = 0.05;
  /// Nearest occupied cells are searched up to this far (d is at most this).
  double weight_max_distance_m = 0.5;
  /// The guard: a particle's pose (matched or sampled) is refused, and odometry's increment
  /// taken from its last pose instead, when its net correction of odometry since the state
  /// of its lineage guard_window_m of travel ago (its first pose while the trajectory is
  /// shorter) exceeds guard_sigmas standard deviations of what the motion model allows over
  /// that motion (heading; position with the heading's lateral error). 0: no guard.
  double guard_sigmas = 3.0;
  double guard_window_m = 10.0;
  /// A particle's pose other than odometry's increment from its last pose (the matched
  /// sample, or else that increment matched) is taken only if
  /// the scan supports it: its likelihood-field log-likelihood minus that of odometry's
  /// increment, on the beams that end where the map has been from both
  /// (fieldLogLikelihood's compared_with), plus the motion model's log prior ratio of the two (-m^2 / 2, m the
  /// correction's Mahalanobis distance under this update's heading and position variances),
  /// is at least correction_min_gain (nats; 0: the more probable of the two under the
  /// motion model and the scan). false: no such test.
  /// The field here is the matcher's kernel: weight_sigma_m is replaced by match_sigma_m. The
  /// weight's 0.15 m is flat on purpose, and with it a heading the matcher got right lost
  /// to the prior at most updates (docs/pose_correction_real.md, "The correction test
  /// scored with the matcher's kernel").
  bool correction_test = true;
  double correction_min_gain = 0.0;
  /// An update once odometry moved this far or turned this much since the last (gmapping's
  /// linearUpdate / angularUpdate); the first scan is always one.
  double update_distance_m = 0.5;
  double update_angle_rad = 0.5;
  /// Resample when N_eff < resample_below * particles (1: at every update).
  double resample_below = 0.5;
  double resolution_m = 0.05;
  double time_step_s = 1.0;           ///< one HMM step of the maps, seconds of sensor time
  double p_hit_given_occ = 0.7;       ///< sensor model, as MapperConfig's
  double p_hit_given_free = 0.2;
  double unknown_p_occ = 0.5;         ///< p(occ) of a cell no scan has reached
  double max_free_range_m = 10.0;     ///< beams without return clear up to here (0: ignored)
  double max_range_m = 30.0;          ///< no beam is walked further (at most 1022 cells)
  /// Scan matching: on by default; off, the proposal is the motion model alone.
  bool scan_matching = true;
  std::size_t match_beam_stride = 2;      ///< every n-th beam with a return takes part
  double match_sigma_m = 0.05;            ///< the score's kernel exp(-d^2 / 2 sigma^2)
  double match_linear_step_m = 0.05;      ///< first step of the hill climb, halved 4 times
  double match_angular_step_rad = 0.03;
  int match_max_iterations = 40;
  /// Matching keeps the motion model's pose unless the score, per beam taking part, is at
  /// least this (a particle's map that has not seen the place yet).
  double match_min_score = 0.2;
  std::uint64_t seed = 1;
  /// Threads for the particles (0 = one per core); results do not depend on it.
  unsigned threads = 0;

  /// Throws std::invalid_argument naming the first bad field.
  void validate() const;
};

/// The laser's poses of a particle, newest first; shared by the particles resampled from it.
struct TrajectoryNode {
  double stamp_s = 0.0;
  Pose2D pose;
  std::shared_ptr<const TrajectoryNode> parent;
  /// For the guard: odometry's pose at this update, the odometry's travel (m) and the
  /// motion model's heading variance (rad^2) and translation variance (m^2) accumulated
  /// since the first update.
  Pose2D odometry;
  double travelled_m = 0.0;
  double heading_variance = 0.0;
  double translation_variance = 0.0;
};

/// The guard's test (PoseFilterConfig::guard_sigmas): whether `pose` at odometry
/// `odometry`, with the totals `travelled_m`, `heading_variance`, `translation_variance`
/// since the first update, stays within `sigmas` standard deviations of odometry's motion
/// since `anchor`: heading |yaw - yaw_pred| <= k sigma_h with sigma_h^2 the heading
/// variance accumulated since the anchor, position |xy - xy_pred| <= k sigma_p with
/// sigma_p^2 = the translation variance since the anchor + (d sigma_h)^2 / 3 (the heading's
/// random walk over the distance d travelled) + (one cell)^2 floor `floor_m`^2; pred is the
/// anchor's pose moved by odometry's motion since the anchor.
bool guardAccepts(const TrajectoryNode& anchor, const Pose2D& pose, const Pose2D& odometry, double travelled_m,
                  double heading_variance, double translation_variance, double sigmas, double floor_m);

/// The distance, in cells, from the point (u, v) of a lattice (cell (x, y) covers
/// [x, x + 1) x [y, y + 1)) to the centre of the nearest cell for which `occupied(x, y)`
/// holds; `max_cells` if there is none within it. Rings of cells (Chebyshev radius r)
/// around the point's cell: every centre in ring r is at least r - 0.5 cells away, so the
/// search stops once that exceeds the best distance.
template <typename Occupied>
double nearestCellDistance(double u, double v, double max_cells, Occupied&& occupied) {
  const auto cx = static_cast<std::int32_t>(std::floor(u));
  const auto cy = static_cast<std::int32_t>(std::floor(v));
  double best_squared = max_cells * max_cells;
  const auto consider = [&](std::int32_t x, std::int32_t y) {
    const double du = u - (x + 0.5);
    const double dv = v - (y + 0.5);
    const double squared = du * du + dv * dv;
    if (squared < best_squared && occupied(x, y)) best_squared = squared;
  };
  const auto max_ring = static_cast<std::int32_t>(std::ceil(max_cells + 0.5));
  for (std::int32_t r = 0; r <= max_ring; ++r) {
    const double nearest = r - 0.5;
    if (nearest > 0.0 && nearest * nearest >= best_squared) break;
    if (r == 0) {
      consider(cx, cy);
      continue;
    }
    for (std::int32_t d = -r; d <= r; ++d) {
      consider(cx + d, cy - r);
      consider(cx + d, cy + r);
    }
    for (std::int32_t d = -r + 1; d <= r - 1; ++d) {
      consider(cx - r, cy + d);
      consider(cx + r, cy + d);
    }
  }
  return std::sqrt(best_squared);
}

/// The distance (m) from (x_m, y_m) to the centre of the nearest cell that `map` has
/// observed and predicts occupied (p > 0.5 at `step`), on a lattice of `resolution_m`;
/// `max_distance_m` if there is none within it.
double nearestOccupiedDistance(const ParticleMap& map, const TransitionSource& transitions, double x_m,
                               double y_m, double resolution_m, double max_distance_m, std::int64_t step,
                               double unknown_p_occ);

/// One beam's term of the weight (PoseFilterConfig::weight_beams): log(weight_z_hit
/// exp(-d^2 / 2 weight_sigma_m^2) + weight_z_rand) for an end `distance_m` from the nearest
/// occupied cell.
double beamLogLikelihood(const PoseFilterConfig& config, double distance_m);

/// The likelihood field's log-likelihood of `beams` (ends in the laser's frame) from `pose`
/// under `map` predicted to `step`: the sum of beamLogLikelihood over the beams, a beam whose
/// end the map has not been near (no observed cell in the 3 x 3 around it) explained
/// (d = 0). With `compared_with`, a beam also counts as explained when its end from
/// `compared_with` is where the map has not been: two poses scored against each other this
/// way are compared on the same beams. (Without it, a pose that puts ends behind a wall, in
/// cells never observed, gains them over a pose that puts them on the wall.)
double fieldLogLikelihood(const ParticleMap& map, const TransitionSource& transitions, const PoseFilterConfig& config,
                          const std::vector<std::array<double, 2>>& beams, const Pose2D& pose, std::int64_t step,
                          const Pose2D* compared_with = nullptr);

/// The beams the weight takes: at most `count` with a return (range_min <= r < range_max),
/// evenly spread over those with one; their ends in the laser's frame (x, y).
std::vector<std::array<double, 2>> weightBeams(const Scan& scan, std::size_t count);

struct Particle {
  Pose2D pose;              ///< the laser's pose in the map frame at the last update
  double log_weight = 0.0;  ///< since the last resampling, up to a constant
  ParticleMap map;
  std::shared_ptr<const TrajectoryNode> trajectory;
};

/// What one scan did.
struct PoseUpdate {
  bool updated = false;   ///< false: odometry had not moved enough (the scan is not used)
  bool resampled = false;
  double effective_sample_size = 0.0;  ///< before resampling
  /// Bytes of the particles' maps after the update (each tile shared by several particles
  /// once): the filter's peak, but for the tile being copied.
  std::size_t map_bytes = 0;
};

/// A scan's evidence for one cell: one hit or one miss (a scan observes a cell once).
struct CellEvidence {
  std::int32_t x = 0;
  std::int32_t y = 0;
  std::uint32_t hits = 0;
  std::uint32_t misses = 0;
};

/// The cells a scan from `laser_pose` reaches on a lattice of `resolution_m` (corner at the
/// origin) and their evidence, in the order the beams first reach them; the reading rules of
/// scan_beams.h and the Mapper's rule of one observation per cell and scan (a hit if any
/// beam ends there with a return, otherwise a miss). Throws std::invalid_argument for a scan
/// scanFieldsError refuses, a beam beyond the lattice, or a scan whose box of cells is
/// wider than 2048 cells (max_range_m too long for resolution_m).
std::vector<CellEvidence> scanEvidence(const Scan& scan, const Pose2D& laser_pose, double resolution_m,
                                       double max_free_range_m, double max_range_m);

class PoseFilter {
 public:
  /// A beam's end in the laser frame (x, y; m).
  using LaserPoint = std::array<double, 2>;

  /// Throws std::invalid_argument for a bad config or a null source.
  PoseFilter(const PoseFilterConfig& config, std::shared_ptr<const TransitionSource> transitions);

  /// A scan whose laser_pose is the laser's *odometry* pose at the scan's stamp. The first
  /// scan puts every particle at that pose (the map frame starts at odometry's) and maps
  /// it; a later one updates the particles once odometry has moved enough (else it is not
  /// used). Stamps must not go back past the first scan's step. Throws
  /// std::invalid_argument (nothing changed) for a scan scanFieldsError or scanEvidence
  /// refuses, a stamp before the last update's step, or a first scan outside step 0 of
  /// startStepsAt's origin.
  PoseUpdate integrate(const Scan& scan);
  /// Before the first scan: step 0 starts at `origin_s` instead of at the first scan's
  /// stamp, which must then be in step 0 (integrate throws std::invalid_argument otherwise),
  /// so that the filter's steps are another clock's (a Mapper's) moved by whole steps. A
  /// later call before the first scan replaces it. Throws std::logic_error once started.
  void startStepsAt(double origin_s);

  const PoseFilterConfig& config() const { return config_; }
  const std::vector<Particle>& particles() const { return particles_; }
  bool started() const { return last_odometry_.has_value(); }
  /// The particle with the highest weight (the first of equals; after resampling, a copy of
  /// the particle that had the highest weight before). Requires started().
  std::size_t bestIndex() const;
  const Particle& best() const { return particles_[bestIndex()]; }
  /// The particles' normalised weights.
  std::vector<double> weights() const;
  double effectiveSampleSize() const;
  /// Entropy (nats) of a Gaussian fitted to the weighted particle poses (x, y, yaw), as
  /// gmapping's ~entropy; a floor of 1e-12 per variance keeps it finite for equal poses.
  double poseEntropy() const;
  /// The map frame's correction of odometry: the best particle's pose times the inverse of
  /// the odometry pose of the last update (map -> odom for the laser's poses).
  Pose2D mapToOdometry() const;
  /// The best particle's trajectory, oldest first.
  std::vector<TrajectoryNode> bestTrajectory() const;
  const TransitionSource& transitions() const { return *transitions_; }
  std::size_t updates() const { return updates_; }
  /// The step of the last update (0 before the first scan's).
  std::int64_t lastUpdateStep() const { return last_step_; }
  std::size_t resamplings() const { return resamplings_; }
  /// Particle-updates whose sample the guard or the correction test refused and that took
  /// odometry's increment (its match refused too, or not moved).
  std::size_t guardRefusals() const { return guard_refusals_; }
  /// N_eff before resampling of every update after the first, in order.
  const std::vector<double>& effectiveSampleSizes() const { return effective_sample_sizes_; }
  /// Wall time (s) spent in the updates after the first.
  double updateSeconds() const { return update_seconds_; }
  /// The filter's steps (started by the first scan): step 0 starts at startStepsAt's origin,
  /// or else at the first scan's stamp.
  const StepClock& clock() const { return clock_; }

 private:
  /// `beams`: the ends of the scan's beams that take part in matching.
  Pose2D matchPose(const Particle& particle, const std::vector<LaserPoint>& beams, const Pose2D& start,
                   std::int64_t step) const;
  /// Moves and weighs one particle (its map is updated after resampling: mapScan); true if
  /// the guard refused its pose.
  bool updateParticle(Particle& particle, const Scan& scan, const std::vector<LaserPoint>& match_beams,
                      const std::vector<LaserPoint>& weight_beams, const OdometryMotion& motion,
                      const std::array<double, 3>& normals, std::int64_t step) const;
  /// Maps `scan` in every particle's map from its pose; `ancestors[i]` the particle that
  /// particle i was copied from at resampling (the copies of one share pose and map: one
  /// update, shared).
  void mapScan(const Scan& scan, const std::vector<std::size_t>& ancestors, std::int64_t step);
  /// One filter step of every cell of `evidence` in `map`.
  void mapEvidence(ParticleMap& map, const std::vector<CellEvidence>& evidence, std::int64_t step) const;
  /// Returns each new particle's index before resampling; the best particle's copies first.
  std::vector<std::size_t> resample();

  PoseFilterConfig config_;
  std::shared_ptr<const TransitionSource> transitions_;
  ObservationModel sensor_;
  StepClock clock_;
  std::mt19937_64 rng_;
  std::vector<Particle> particles_;
  std::optional<Pose2D> last_odometry_;  ///< at the last update
  std::int64_t last_step_ = 0;           ///< the last update's step
  std::optional<double> steps_origin_s_;  ///< startStepsAt's, until the first scan
  std::size_t updates_ = 0;
  std::size_t resamplings_ = 0;
  std::size_t guard_refusals_ = 0;
  std::vector<double> effective_sample_sizes_;
  double update_seconds_ = 0.0;
};

}  // namespace core
}  // namespace dynamic_occupancy_grid
