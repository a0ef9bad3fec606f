#pragma once
// Does online learning pay off? (docs/online_learning.md) The same scans of a simulated run
// mapped by several learners side by side with the honest baselines, scored where the
// package matters: accuracy on the cells that change, in the converged window (the run's
// last part), the learned parameters against the truth per kind of cell, what `belief`
// still shows of the places the robot left, and how many static cells are learned as
// changing.
//
// Methods, all fed the same scans with the same sensor model:
//   static        the package's static_map (clamped log-odds; the same in every mapper)
//   node_static   static_map as a user gets it who sets no sensor model: the package's
//                 default start (0.7 / 0.2)
//   node_default  the default learner from that start, learning the sensor model (the
//                 node's defaults: "no parameter set to the world")
//   textbook      the textbook occupancy grid (log-odds, no clamp)
//   learning_off  the HMM filter with MapperConfig::prior_transitions fixed
//   <variant>     the HMM filter learning online with the variant's settings
//   offline       transitions from offline EM on a training run of the same world, fixed
//   oracle        the world's true transitions, fixed
//
// ROS-free: standard library only.

#include <array>
#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/evaluation/simulator.h"

namespace dynamic_occupancy_grid {
namespace evaluation {

/// An online learner to compare: a name and the settings that differ from the defaults
/// (applied to the scenario's mapper configuration, see evaluationMapperConfig).
struct LearnerVariant {
  std::string name;
  std::function<void(core::MapperConfig&)> configure;
};
/// The learners of the comparison in docs/online_learning.md: "default" (the package's
/// defaults: kinds of cells, cell_kinds.h), "cell_em" (each cell's own online EM with the
/// 1/t schedule, the default before).
std::vector<LearnerVariant> defaultLearnerVariants();

struct LearningExperimentConfig {
  int repetitions = 4;
  std::uint64_t seed = 1;  ///< repetition r's world and run seeds are derived from (seed, r)
  unsigned threads = 0;    ///< repetitions run in parallel; 0 = one per core
  /// The converged window: accuracy is averaged over the run's steps from
  /// (1 - window_fraction) * steps on.
  double window_fraction = 0.5;
  /// "The robot has left": cells not observed in this many steps before the end.
  std::int64_t left_for_steps = 60;
  std::vector<LearnerVariant> variants = defaultLearnerVariants();
  /// Also the methods node_static and node_default (see above).
  bool node_defaults = true;
  /// Every online method (static, textbook, learning_off, the variants, the oracle) learns
  /// the sensor model online, as the node does by default (~learn_sensor_model), and
  /// offline EM learns it with the transitions; false keeps the scenario's configured model.
  bool learn_sensor_model = true;
};

/// One kind of cell: a truth shared by its cells (dynamic cells grouped by their true
/// parameters, static cells by their state).
struct KindScore {
  std::string kind;                ///< "static free", "static occupied" or "p_of / p_fo"
  core::TransitionParams truth;
  double cells = 0.0;              ///< observed cells per run (mean)
  /// Mean absolute error of the learned transitions over the cells, and the median learned
  /// values (both pooled over repetitions).
  double mae_p_occ_given_free = 0.0;
  double mae_p_free_given_occ = 0.0;
  double median_p_occ_given_free = 0.0;
  double median_p_free_given_occ = 0.0;
  /// Learners of kinds (TransitionLearner::kKinds) only: the share of the cells whose most
  /// probable kind at the end is kind k (pooled over repetitions); zeros otherwise.
  std::array<double, core::kKindCount> most_probable_kind{};
};

struct MethodScore {
  std::string method;
  /// Per repetition, accuracy (THEORY.md §9) in the converged window over all cells and
  /// over the cells that change (the world's dynamic cells).
  std::vector<double> accuracy_all;
  std::vector<double> accuracy_changing;
  /// Accuracy in the converged window per kind of cell (KindScore::kind), pooled over
  /// repetitions.
  std::map<std::string, double> accuracy_by_kind;
  /// Transition methods only: per kind of cell, at the end of the run.
  std::vector<KindScore> kinds;
  /// Dynamic cells, at the end of the run: mean absolute error of both parameters
  /// (the mean of the p_of and p_fo errors), per repetition.
  std::vector<double> dynamic_mae;
  /// At the end, among the cells static_map classifies (map_server's trinary thresholds,
  /// free < 0.196, occupied > 0.65) that were not observed in the last left_for_steps
  /// steps: the share this method classifies the same way (per repetition).
  std::vector<double> retention;
  /// Static cells whose learned probability of leaving their true state exceeds 0.05 (a
  /// wall's p_free_given_occ, a free cell's p_occ_given_free), per run (mean), and how many
  /// static cells of each state were observed.
  double static_occupied_changing = 0.0;
  double static_free_changing = 0.0;
  double static_occupied_cells = 0.0;
  double static_free_cells = 0.0;
  /// Learned sensor model at the end (online variants; the configured one otherwise), mean.
  double p_hit_given_occ = 0.0;
  double p_hit_given_free = 0.0;
  /// Learners of kinds only (empty otherwise): per repetition, each kind's transitions and
  /// share of the cells at the end (CellKinds::transitions, weight).
  std::vector<std::array<core::TransitionParams, core::kKindCount>> kind_transitions;
  std::vector<std::array<double, core::kKindCount>> kind_weights;
};

struct LearningExperimentResult {
  std::string scenario;
  /// static, [node_static, node_default,] textbook, learning_off, variants..., offline, oracle
  std::vector<MethodScore> methods;
  /// The simulated laser's hit rates on occupied and free cells, measured on the runs.
  double laser_hit_rate_occ = 0.0;
  double laser_hit_rate_free = 0.0;
  double seconds = 0.0;
  const MethodScore& method(const std::string& name) const;
};

/// Runs the comparison on `scenario`. Throws std::invalid_argument for bad settings.
LearningExperimentResult runLearningExperiment(const ScenarioConfig& scenario, const LearningExperimentConfig& config,
                                               const std::function<void(int done)>& progress = {});

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
