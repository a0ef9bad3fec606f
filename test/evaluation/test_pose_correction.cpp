// Tests of the pose-correction comparison (evaluation/pose_correction.h) on a short patrol
// of the office with drifting odometry: the filters with a static and with the true
// transitions' map end far nearer the truth than odometry (the learned one at least halves
// its error), the known-pose map is the best map, and the tables have their rows.

#include "dynamic_occupancy_grid/evaluation/pose_correction.h"

#include <gtest/gtest.h>

#include <iostream>
#include <limits>
#include <sstream>
#include <string>

namespace evaluation = dynamic_occupancy_grid::evaluation;

namespace {

const evaluation::PoseEstimatorResult& find(const evaluation::PoseCorrectionResult& result, const std::string& name) {
  for (const auto& e : result.estimators) {
    if (e.name == name) return e;
  }
  throw std::runtime_error("no estimator " + name);
}

TEST(PoseCorrection, FiltersBeatOdometryOnAPatrol) {
  evaluation::PoseCorrectionConfig config;
  config.steps = 200;
  config.filter.particles = 10;
  const evaluation::PoseCorrectionResult result = evaluation::runPoseCorrection(config);
  for (const auto& e : result.estimators) {
    std::cout << e.name << ": ATE " << e.ate_rmse_m << " m, RPE " << e.rpe_trans_rmse_m << " m / " << e.rpe_rot_rmse_rad
              << " rad, final " << e.final_error_m << " m, changing " << e.changing_accuracy << ", static "
              << e.static_accuracy << ", " << e.ms_per_update << " ms/update, " << e.updates << " updates, "
              << e.resamplings << " resamplings\n";
  }
  for (const auto& e : result.learned) {
    std::cout << e.learner << ' ' << e.kind << ": " << e.cells << " cells, MAE " << e.mae_p_occ_given_free << " / "
              << e.mae_p_free_given_occ << ", learned as changing " << e.learned_changing_share << "\n";
  }
  ASSERT_EQ(result.estimators.size(), 5u);
  EXPECT_EQ(result.scans, 400u);
  EXPECT_EQ(find(result, "known_pose").ate_rmse_m, 0.0);
  const double odometry = find(result, "odometry").ate_rmse_m;
  EXPECT_GT(odometry, 0.3);
  const evaluation::PoseEstimatorResult& known = find(result, "known_pose");
  for (const char* name : {"rbpf_static", "rbpf_hmm", "rbpf_oracle"}) {
    const evaluation::PoseEstimatorResult& filter = find(result, name);
    // The map with learned transitions is not reliable yet (docs/pose_correction.md: it
    // loses the robot in some runs; here 0.16 m, with 10 steps instead of 30 before a
    // learned cell counts 1.6 m): only the drift halved is asked of it.
    const bool learned = std::string(name) == "rbpf_hmm";
    EXPECT_LT(filter.ate_rmse_m, (learned ? 0.5 : 0.2) * odometry) << name;
    if (!learned) EXPECT_LT(filter.ate_rmse_m, 0.5) << name;
    EXPECT_GT(filter.static_accuracy, find(result, "odometry").static_accuracy + 0.05) << name;
    EXPECT_LE(filter.static_accuracy, known.static_accuracy) << name;
    EXPECT_GT(filter.updates, 100u) << name;
  }
  // The world's true transitions in the particles' maps: close to the bound on the cells
  // that change (the filters' maps are a particle's, re-drawn at every resampling).
  EXPECT_GT(find(result, "rbpf_oracle").changing_accuracy, known.changing_accuracy - 0.05);
  EXPECT_GT(known.static_accuracy, 0.99);
  const auto tables = evaluation::poseCorrectionCsvTables({result, result});
  EXPECT_NE(evaluation::formatPoseCorrectionSummary(config, {result}).find("| rbpf_hmm |"), std::string::npos);
  ASSERT_EQ(tables.count("pose_correction_errors.csv"), 1u);
  std::istringstream trajectory(tables.at("pose_correction_trajectory.csv"));
  std::string line;
  int lines = 0;
  while (std::getline(trajectory, line)) ++lines;
  EXPECT_EQ(lines, 401);
  std::istringstream errors(tables.at("pose_correction_errors.csv"));
  lines = 0;
  while (std::getline(errors, line)) ++lines;
  EXPECT_EQ(lines, 1 + 2 * 5);
  // The learned transitions per kind of cell (both learners on the cells the known-pose map
  // observed): the known-pose learner's walls and free space static, its changing cells not.
  ASSERT_EQ(result.learned.size(), 6u);
  const char* kinds[3] = {"static_occupied", "static_free", "changing"};
  for (std::size_t k = 0; k < 3; ++k) {
    const evaluation::LearnedTransitionError& at_truth = result.learned[k];
    const evaluation::LearnedTransitionError& filtered = result.learned[3 + k];
    EXPECT_EQ(at_truth.learner, "known_pose");
    EXPECT_EQ(filtered.learner, "rbpf_hmm");
    EXPECT_EQ(at_truth.kind, kinds[k]);
    EXPECT_EQ(filtered.kind, kinds[k]);
    EXPECT_GT(at_truth.cells, 100u) << kinds[k];
  }
  EXPECT_LT(result.learned[0].learned_changing_share, 0.01);
  EXPECT_LT(result.learned[1].learned_changing_share, 0.01);
  EXPECT_LT(result.learned[0].mae_p_free_given_occ, 0.002);
  // Doors, carts, people seen often enough: in these 400 steps (four loops) 3.5 % of them;
  // a place is learned as changing once revisits show it changing with time, until then
  // part of its posterior stays on the stable kind, whose changes are the view's
  // (cell_kinds.h).
  EXPECT_GT(result.learned[2].learned_changing_share, 0.02);
  std::istringstream learned(tables.at("pose_correction_learned.csv"));
  lines = 0;
  while (std::getline(learned, line)) ++lines;
  EXPECT_EQ(lines, 1 + 2 * 6);
  EXPECT_NE(evaluation::formatPoseCorrectionSummary(config, {result}).find("| rbpf_hmm | static_occupied |"),
            std::string::npos);
}

}  // namespace
