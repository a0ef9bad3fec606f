#pragma once
// Mapping under pose uncertainty, measured (issue 19; core/pose/pose_filter.h): one simulated
// run of a changing world, the same scans, the laser's pose known only through drifting
// odometry, mapped side by side by
//   known_pose   the package's Mapper at the true laser poses (the bound)
//   odometry     the Mapper at the odometry poses (no correction)
//   rbpf_static  the pose filter whose particle maps never change (transitions {0, 0}: a
//                gmapping-like static map)
//   rbpf_hmm     the pose filter whose particle maps are cell HMMs with the transitions the
//                package's learner (the default Mapper) learns from the scans at the
//                filter's corrected poses
//   rbpf_oracle  the same with the world's true transitions (what learning could reach)
// Trajectory error as evo computes it (absolute: RMSE of the positions; relative: RMSE of
// the motion over a fixed number of scans), and each map's accuracy at the end of every
// step of the run's second half, on the cells that change and on the static cells, against
// the truth of that step. The filters' estimate at a scan is the online one (the best
// particle's correction of that scan's odometry), as a robot uses it. At the end, the
// transitions rbpf_hmm's learner learned against the truth, per kind of cell, beside those
// the known-pose Mapper learned from the same scans.
//
// ROS-free: standard library only.

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/pose/motion_model.h"
#include "dynamic_occupancy_grid/core/pose/pose_filter.h"
#include "dynamic_occupancy_grid/evaluation/simulator.h"

namespace dynamic_occupancy_grid {
namespace evaluation {

struct PoseCorrectionConfig {
  std::string scenario = "patrol_office";
  std::int64_t steps = 400;   ///< of the scenario (patrol_office: 100 a loop)
  std::uint64_t world_seed = 1;
  std::uint64_t run_seed = 1;
  /// The odometry's drift (amcl's alphas; the simulator's DriftingOdometry).
  core::OdometryNoise odometry_noise{0.02, 0.001, 0.01, 0.005};
  /// The filters' settings (resolution, time step and sensor model come from the scenario).
  core::PoseFilterConfig filter;
  std::size_t relative_error_scans = 10;  ///< the relative error's span
  /// rbpf_hmm: cells its learner has observed in fewer steps stay static (MapperTransitions).
  std::uint32_t learned_min_observed_steps = 30;
  /// Throws std::invalid_argument naming the first bad field.
  void validate() const;
};

struct PoseEstimatorResult {
  std::string name;
  double ate_rmse_m = 0.0;        ///< absolute trajectory error (positions, RMSE)
  double rpe_trans_rmse_m = 0.0;  ///< relative error of the translation over the span
  double rpe_rot_rmse_rad = 0.0;
  double final_error_m = 0.0;     ///< position error at the last scan
  double changing_accuracy = 0.0; ///< p > 0.5 agrees with the truth, cells that change
  double static_accuracy = 0.0;   ///< the same, static cells the known-pose map observed
  double ms_per_update = 0.0;     ///< filters: wall time per update (all particles)
  std::size_t updates = 0;
  std::size_t resamplings = 0;
};

/// One learner's transitions against the world's at the end of a run, on one kind of cell
/// (static_occupied, static_free, changing) of those the known-pose map observed, read as
/// the filter reads them (MapperTransitions: static until observed in
/// learned_min_observed_steps steps).
struct LearnedTransitionError {
  std::string learner;  ///< known_pose (the Mapper at the true poses) or rbpf_hmm (its learner)
  std::string kind;
  std::size_t cells = 0;
  double mae_p_occ_given_free = 0.0;  ///< mean |learned - true|, per step
  double mae_p_free_given_occ = 0.0;
  /// Cells learned as changing: the rate of leaving their true state (a changing cell: either
  /// rate) above kLearnedChangingRate per step.
  double learned_changing_share = 0.0;
};

/// Above it a cell is "learned as changing": it forgets its state within about 200 steps
/// (two loops of patrol_office).
constexpr double kLearnedChangingRate = 0.005;

struct PoseCorrectionResult {
  std::vector<PoseEstimatorResult> estimators;  ///< in the order of the header's list
  std::vector<LearnedTransitionError> learned;  ///< known_pose's three kinds, then rbpf_hmm's
  std::size_t scans = 0;
  std::size_t changing_cells = 0;
  std::size_t static_cells = 0;
  /// Per scan: stamp, the true pose, odometry's and each filter's estimate (rows of the CSV).
  std::vector<std::vector<double>> trajectory_rows;
  std::vector<std::string> trajectory_columns;
};

/// Runs the comparison (filters on config.filter.threads threads).
PoseCorrectionResult runPoseCorrection(const PoseCorrectionConfig& config);

/// CSV tables of several runs: pose_correction_errors.csv (a row per run and estimator)
/// and pose_correction_trajectory.csv (the first run's, a row per scan).
std::map<std::string, std::string> poseCorrectionCsvTables(const std::vector<PoseCorrectionResult>& runs);

/// The summary's section: the means over the runs per estimator, then each run.
std::string formatPoseCorrectionSummary(const PoseCorrectionConfig& config, const std::vector<PoseCorrectionResult>& runs);

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
