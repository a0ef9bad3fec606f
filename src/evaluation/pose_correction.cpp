#include "dynamic_occupancy_grid/evaluation/pose_correction.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <memory>
#include <optional>
#include <sstream>
#include <stdexcept>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/evaluation/evaluation.h"

namespace dynamic_occupancy_grid {
namespace evaluation {

namespace {

/// The world's true transitions (static outside it): what a perfect learner would give.
class WorldTransitions final : public core::TransitionSource {
 public:
  explicit WorldTransitions(const World& world) : world_(world) {}
  core::TransitionParams at(std::int32_t x, std::int32_t y) const override {
    return world_.inside(x, y) ? world_.truth(x, y) : core::TransitionParams{0.0, 0.0};
  }

 private:
  const World& world_;
};

struct CellAccuracy {
  std::size_t right = 0;
  std::size_t total = 0;
  double fraction() const { return total == 0 ? 0.0 : static_cast<double>(right) / static_cast<double>(total); }
};

/// `learner`'s transitions, as `transitions` reads them, against the world's on the cells
/// `observed` (the known-pose map's), one row per kind of cell.
std::vector<LearnedTransitionError> learnedTransitionErrors(const std::string& learner,
                                                            const core::TransitionSource& transitions,
                                                            const World& world, const core::Mapper& observed) {
  std::vector<LearnedTransitionError> rows(3);
  rows[0].kind = "static_occupied";
  rows[1].kind = "static_free";
  rows[2].kind = "changing";
  std::vector<std::size_t> changing(3, 0);
  for (std::int32_t y = 0; y < world.height(); ++y) {
    for (std::int32_t x = 0; x < world.width(); ++x) {
      const std::optional<core::CellState> seen = observed.grid().cell(x, y);
      if (!seen || seen->last_step == core::kNeverObserved) continue;
      const core::TransitionParams truth = world.truth(x, y);
      const std::size_t kind = !truth.isStatic() ? 2 : world.occupied(x, y) ? 0 : 1;
      const core::TransitionParams learned = transitions.at(x, y);
      LearnedTransitionError& row = rows[kind];
      ++row.cells;
      row.mae_p_occ_given_free += std::abs(learned.p_occ_given_free - truth.p_occ_given_free);
      row.mae_p_free_given_occ += std::abs(learned.p_free_given_occ - truth.p_free_given_occ);
      const double leaving = kind == 0   ? learned.p_free_given_occ
                             : kind == 1 ? learned.p_occ_given_free
                                         : std::max(learned.p_occ_given_free, learned.p_free_given_occ);
      changing[kind] += leaving > kLearnedChangingRate ? 1 : 0;
    }
  }
  for (std::size_t k = 0; k < rows.size(); ++k) {
    rows[k].learner = learner;
    if (rows[k].cells == 0) continue;
    const double n = static_cast<double>(rows[k].cells);
    rows[k].mae_p_occ_given_free /= n;
    rows[k].mae_p_free_given_occ /= n;
    rows[k].learned_changing_share = static_cast<double>(changing[k]) / n;
  }
  return rows;
}

struct TrajectoryErrors {
  double ate = 0.0;
  double rpe_trans = 0.0;
  double rpe_rot = 0.0;
  double final_error = 0.0;
};

TrajectoryErrors trajectoryErrors(const std::vector<core::Pose2D>& estimate, const std::vector<core::Pose2D>& truth,
                                  std::size_t span) {
  TrajectoryErrors errors;
  double squares = 0.0;
  for (std::size_t i = 0; i < truth.size(); ++i) {
    const double dx = estimate[i].x_m - truth[i].x_m;
    const double dy = estimate[i].y_m - truth[i].y_m;
    squares += dx * dx + dy * dy;
  }
  errors.ate = std::sqrt(squares / static_cast<double>(truth.size()));
  errors.final_error = std::hypot(estimate.back().x_m - truth.back().x_m, estimate.back().y_m - truth.back().y_m);
  // evo's RPE: the error of the estimated motion over `span` scans against the true one.
  double trans = 0.0;
  double rot = 0.0;
  std::size_t pairs = 0;
  for (std::size_t i = 0; i + span < truth.size(); ++i) {
    const core::Pose2D true_motion = core::relativePose(truth[i], truth[i + span]);
    const core::Pose2D estimated_motion = core::relativePose(estimate[i], estimate[i + span]);
    const core::Pose2D error = core::relativePose(true_motion, estimated_motion);
    trans += error.x_m * error.x_m + error.y_m * error.y_m;
    rot += error.yaw_rad * error.yaw_rad;
    ++pairs;
  }
  if (pairs > 0) {
    errors.rpe_trans = std::sqrt(trans / static_cast<double>(pairs));
    errors.rpe_rot = std::sqrt(rot / static_cast<double>(pairs));
  }
  return errors;
}

/// A pose filter with its run's bookkeeping.
struct FilterRun {
  std::string name;
  std::unique_ptr<core::PoseFilter> filter;
  std::vector<core::Pose2D> estimate;  ///< per scan
  double update_ms = 0.0;
  CellAccuracy changing;
  CellAccuracy still;
};

}  // namespace

void PoseCorrectionConfig::validate() const {
  scenarioConfig(scenario);  // throws for an unknown name
  if (steps < 2) throw std::invalid_argument("PoseCorrectionConfig: steps must be >= 2");
  odometry_noise.validate();
  if (relative_error_scans < 1) throw std::invalid_argument("PoseCorrectionConfig: relative_error_scans must be >= 1");
  filter.validate();
}

PoseCorrectionResult runPoseCorrection(const PoseCorrectionConfig& config) {
  config.validate();
  const ScenarioConfig scenario = scenarioConfig(config.scenario);
  Simulation simulation(scenario, config.world_seed, config.run_seed);
  const World& world = simulation.world();
  DriftingOdometry odometry(config.odometry_noise, mixSeed(config.run_seed ^ 0x6f646f6dULL));

  const core::MapperConfig mapper_config = evaluationMapperConfig(scenario);
  core::Mapper known(mapper_config);
  core::Mapper dead_reckoning(mapper_config);
  core::Mapper learner(mapper_config);  // the package's learner on the scans at rbpf_hmm's poses

  core::PoseFilterConfig filter_config = config.filter;
  filter_config.resolution_m = scenario.resolution_m;
  filter_config.time_step_s = scenario.time_step_s;
  filter_config.p_hit_given_occ = scenario.p_hit_given_occ;
  filter_config.p_hit_given_free = scenario.p_hit_given_free;
  filter_config.max_free_range_m = mapper_config.max_free_range_m;
  std::vector<FilterRun> filters(3);
  filters[0].name = "rbpf_static";
  filters[0].filter = std::make_unique<core::PoseFilter>(
      filter_config, std::make_shared<core::UniformTransitions>(core::TransitionParams{0.0, 0.0}));
  filters[1].name = "rbpf_hmm";
  filters[1].filter = std::make_unique<core::PoseFilter>(
      filter_config,
      std::make_shared<core::MapperTransitions>(learner, scenario.resolution_m, config.learned_min_observed_steps));
  filters[2].name = "rbpf_oracle";
  filters[2].filter = std::make_unique<core::PoseFilter>(filter_config, std::make_shared<WorldTransitions>(world));

  std::vector<core::Pose2D> truth;
  std::vector<core::Pose2D> odometry_track;
  std::vector<double> stamps;
  CellAccuracy known_changing, known_still, odometry_changing, odometry_still;
  const std::int64_t score_from = config.steps / 2;
  const auto score_mapper = [&world](const core::Mapper& mapper, std::int32_t x, std::int32_t y, std::int64_t step,
                                     CellAccuracy& accuracy) {
    const std::optional<core::CellState> cell = mapper.grid().cell(x, y);
    const bool known_cell = cell && cell->last_step != core::kNeverObserved;
    const double p = known_cell ? mapper.beliefAt(x, y, step) : 0.5;
    ++accuracy.total;
    accuracy.right += known_cell && p != 0.5 && (p > 0.5) == world.occupied(x, y) ? 1 : 0;
  };

  for (std::int64_t t = 0; t < config.steps; ++t) {
    for (int k = 0; k < scenario.scans_per_step; ++k) {
      const core::Scan scan = simulation.scan(k);
      const core::Pose2D robot_odometry = odometry.update(simulation.robotPose(k));
      const core::Pose2D laser_odometry = core::composePose(robot_odometry, scenario.laser_mount);
      core::Scan odometry_scan = scan;
      odometry_scan.laser_pose = laser_odometry;
      for (core::Mapper* mapper : {&known, &dead_reckoning}) {
        const core::ScanResult result = mapper->integrate(mapper == &known ? scan : odometry_scan);
        if (result.status != core::ScanStatus::kIntegrated)
          throw std::runtime_error("pose correction: scan rejected: " + result.error);
      }
      for (FilterRun& run : filters) {
        const auto start = std::chrono::steady_clock::now();
        const core::PoseUpdate update = run.filter->integrate(odometry_scan);
        if (update.updated) {
          run.update_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
        }
        run.estimate.push_back(core::composePose(run.filter->mapToOdometry(), laser_odometry));
      }
      core::Scan corrected = scan;
      corrected.laser_pose = filters[1].estimate.back();
      learner.integrate(corrected);
      truth.push_back(scan.laser_pose);
      odometry_track.push_back(laser_odometry);
      stamps.push_back(scan.stamp_s);
    }
    for (core::Mapper* mapper : {&known, &dead_reckoning}) mapper->finishStep();
    learner.finishStep();
    if (t >= score_from) {
      for (std::int32_t y = 0; y < world.height(); ++y) {
        for (std::int32_t x = 0; x < world.width(); ++x) {
          const std::optional<core::CellState> seen = known.grid().cell(x, y);
          if (!seen || seen->last_step == core::kNeverObserved) continue;  // the cells the bound maps
          const bool changing = !world.truth(x, y).isStatic();
          score_mapper(known, x, y, t, changing ? known_changing : known_still);
          score_mapper(dead_reckoning, x, y, t, changing ? odometry_changing : odometry_still);
          for (FilterRun& run : filters) {
            const core::Particle& best = run.filter->best();
            const bool observed = best.map.lastStep(x, y) != core::kNeverObserved;
            const double p = best.map.predicted(x, y, t, run.filter->transitions(), filter_config.unknown_p_occ);
            CellAccuracy& accuracy = changing ? run.changing : run.still;
            ++accuracy.total;
            accuracy.right += observed && p != 0.5 && (p > 0.5) == world.occupied(x, y) ? 1 : 0;
          }
        }
      }
    }
    simulation.advance();
  }

  PoseCorrectionResult result;
  result.scans = truth.size();
  for (const auto& [name, mapper] :
       {std::pair<const char*, const core::Mapper*>{"known_pose", &known}, {"rbpf_hmm", &learner}}) {
    const core::MapperTransitions transitions(*mapper, scenario.resolution_m, config.learned_min_observed_steps);
    for (LearnedTransitionError& row : learnedTransitionErrors(name, transitions, world, known)) {
      result.learned.push_back(std::move(row));
    }
  }
  const auto add = [&](const std::string& name, const std::vector<core::Pose2D>& track, const CellAccuracy& changing,
                       const CellAccuracy& still) -> PoseEstimatorResult& {
    PoseEstimatorResult estimator;
    estimator.name = name;
    const TrajectoryErrors errors = trajectoryErrors(track, truth, config.relative_error_scans);
    estimator.ate_rmse_m = errors.ate;
    estimator.rpe_trans_rmse_m = errors.rpe_trans;
    estimator.rpe_rot_rmse_rad = errors.rpe_rot;
    estimator.final_error_m = errors.final_error;
    estimator.changing_accuracy = changing.fraction();
    estimator.static_accuracy = still.fraction();
    result.estimators.push_back(estimator);
    return result.estimators.back();
  };
  add("known_pose", truth, known_changing, known_still);
  add("odometry", odometry_track, odometry_changing, odometry_still);
  for (const FilterRun& run : filters) {
    PoseEstimatorResult& estimator = add(run.name, run.estimate, run.changing, run.still);
    estimator.updates = run.filter->updates();
    estimator.resamplings = run.filter->resamplings();
    estimator.ms_per_update = run.update_ms / static_cast<double>(std::max<std::size_t>(1, run.filter->updates()));
  }
  result.changing_cells = known_changing.total / static_cast<std::size_t>(std::max<std::int64_t>(1, config.steps - score_from));
  result.static_cells = known_still.total / static_cast<std::size_t>(std::max<std::int64_t>(1, config.steps - score_from));
  result.trajectory_columns = {"stamp_s", "true_x", "true_y", "true_yaw", "odometry_x", "odometry_y", "odometry_yaw"};
  for (const FilterRun& run : filters) {
    for (const char* axis : {"_x", "_y", "_yaw"}) result.trajectory_columns.push_back(run.name + axis);
  }
  for (std::size_t i = 0; i < truth.size(); ++i) {
    std::vector<double> row = {stamps[i],           truth[i].x_m,          truth[i].y_m,
                               truth[i].yaw_rad,    odometry_track[i].x_m, odometry_track[i].y_m,
                               odometry_track[i].yaw_rad};
    for (const FilterRun& run : filters) {
      row.insert(row.end(), {run.estimate[i].x_m, run.estimate[i].y_m, run.estimate[i].yaw_rad});
    }
    result.trajectory_rows.push_back(std::move(row));
  }
  return result;
}

std::map<std::string, std::string> poseCorrectionCsvTables(const std::vector<PoseCorrectionResult>& runs) {
  std::map<std::string, std::string> tables;
  std::ostringstream errors;
  errors << std::setprecision(9);
  errors << "run,estimator,ate_rmse_m,rpe_trans_rmse_m,rpe_rot_rmse_rad,final_error_m,changing_accuracy,static_accuracy,"
            "ms_per_update,updates,resamplings\n";
  for (std::size_t r = 0; r < runs.size(); ++r) {
    for (const PoseEstimatorResult& e : runs[r].estimators) {
      errors << r << ',' << e.name << ',' << e.ate_rmse_m << ',' << e.rpe_trans_rmse_m << ',' << e.rpe_rot_rmse_rad << ','
             << e.final_error_m << ',' << e.changing_accuracy << ',' << e.static_accuracy << ',' << e.ms_per_update
             << ',' << e.updates << ',' << e.resamplings << '\n';
    }
  }
  tables["pose_correction_errors.csv"] = errors.str();
  std::ostringstream learned;
  learned << std::setprecision(9);
  learned << "run,learner,kind,cells,mae_p_occ_given_free,mae_p_free_given_occ,learned_changing_share\n";
  for (std::size_t r = 0; r < runs.size(); ++r) {
    for (const LearnedTransitionError& e : runs[r].learned) {
      learned << r << ',' << e.learner << ',' << e.kind << ',' << e.cells << ',' << e.mae_p_occ_given_free << ','
              << e.mae_p_free_given_occ << ',' << e.learned_changing_share << '\n';
    }
  }
  tables["pose_correction_learned.csv"] = learned.str();
  if (runs.empty()) return tables;
  std::ostringstream trajectory;
  trajectory << std::setprecision(9);
  const PoseCorrectionResult& first = runs.front();
  for (std::size_t c = 0; c < first.trajectory_columns.size(); ++c) trajectory << (c ? "," : "") << first.trajectory_columns[c];
  trajectory << '\n';
  for (const std::vector<double>& row : first.trajectory_rows) {
    for (std::size_t c = 0; c < row.size(); ++c) trajectory << (c ? "," : "") << row[c];
    trajectory << '\n';
  }
  tables["pose_correction_trajectory.csv"] = trajectory.str();
  return tables;
}

std::string formatPoseCorrectionSummary(const PoseCorrectionConfig& config, const std::vector<PoseCorrectionResult>& runs) {
  std::ostringstream out;
  out << std::fixed;
  out << "\n## Mapping under pose uncertainty (" << config.scenario << ", " << runs.size() << " runs of " << config.steps
      << " steps, " << config.filter.particles << " particles)\n\n"
      << std::setprecision(3) << "Odometry drifts (alphas " << config.odometry_noise.rot_from_rot << ", " << config.odometry_noise.rot_from_trans
      << ", " << config.odometry_noise.trans_from_trans << ", " << config.odometry_noise.trans_from_rot
      << "); the laser's pose is known only through it. Trajectory errors over every scan; map accuracy at the end of "
         "every step of the second half (p > 0.5 against the truth; a cell the map never observed counts as wrong), "
         "on the cells the known-pose map observed. Means over the runs:\n\n"
      << "| estimator | ATE (m) | RPE trans (m, " << config.relative_error_scans << " scans) | RPE rot (rad) | "
         "final error (m) | changing cells | static cells | ms per update |\n|---|---|---|---|---|---|---|---|\n";
  if (runs.empty()) return out.str();
  for (std::size_t e = 0; e < runs.front().estimators.size(); ++e) {
    PoseEstimatorResult mean;
    for (const PoseCorrectionResult& run : runs) {
      const PoseEstimatorResult& r = run.estimators[e];
      mean.ate_rmse_m += r.ate_rmse_m / runs.size();
      mean.rpe_trans_rmse_m += r.rpe_trans_rmse_m / runs.size();
      mean.rpe_rot_rmse_rad += r.rpe_rot_rmse_rad / runs.size();
      mean.final_error_m += r.final_error_m / runs.size();
      mean.changing_accuracy += r.changing_accuracy / runs.size();
      mean.static_accuracy += r.static_accuracy / runs.size();
      mean.ms_per_update += r.ms_per_update / runs.size();
    }
    out << "| " << runs.front().estimators[e].name << " | " << std::setprecision(3) << mean.ate_rmse_m << " | "
        << mean.rpe_trans_rmse_m << " | " << mean.rpe_rot_rmse_rad << " | " << mean.final_error_m << " | "
        << std::setprecision(4) << mean.changing_accuracy << " | " << mean.static_accuracy << " | " << std::setprecision(1)
        << mean.ms_per_update << " |\n";
  }
  out << "\nThe transitions learned by the end of the run against the truth, per kind of cell the known-pose map "
         "observed (means over the runs; learned as changing: the rate of leaving the true state, for a changing "
         "cell either rate, above "
      << std::setprecision(3) << kLearnedChangingRate
      << " per step):\n\n| learner | kind | cells | MAE p(occ\\|free) | MAE p(free\\|occ) | learned as changing |\n"
         "|---|---|---|---|---|---|\n";
  for (std::size_t k = 0; k < runs.front().learned.size(); ++k) {
    double cells = 0.0, mae_of = 0.0, mae_fo = 0.0, share = 0.0;
    for (const PoseCorrectionResult& run : runs) {
      const LearnedTransitionError& e = run.learned[k];
      cells += static_cast<double>(e.cells) / runs.size();
      mae_of += e.mae_p_occ_given_free / runs.size();
      mae_fo += e.mae_p_free_given_occ / runs.size();
      share += e.learned_changing_share / runs.size();
    }
    const LearnedTransitionError& first = runs.front().learned[k];
    out << "| " << first.learner << " | " << first.kind << " | " << std::setprecision(0) << cells << " | "
        << std::setprecision(5) << mae_of << " | " << mae_fo << " | " << std::setprecision(1) << 100.0 * share
        << " % |\n";
  }
  out << "\nPer run (ATE in m; changing-cell accuracy):\n\n| run |";
  for (const PoseEstimatorResult& e : runs.front().estimators) out << ' ' << e.name << " |";
  out << "\n|---|";
  for (std::size_t e = 0; e < runs.front().estimators.size(); ++e) out << "---|";
  out << '\n';
  for (std::size_t r = 0; r < runs.size(); ++r) {
    out << "| " << r << " |";
    for (const PoseEstimatorResult& e : runs[r].estimators) {
      out << ' ' << std::setprecision(3) << e.ate_rmse_m << "; " << std::setprecision(3) << e.changing_accuracy << " |";
    }
    out << '\n';
  }
  return out.str();
}

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
