#pragma once
// The evaluation of the papers on simulated worlds (simulator.h): the same scans mapped by
// every method side by side, the accuracy of THEORY.md §9 against the true state of the
// cells, and the error of the learned transition probabilities against the truth.
//
// Methods:
//   static            the standard occupancy grid as this package publishes it (the static
//                     layer: log-odds clamped to MapperConfig::static_clamp)
//   static_unclamped  the textbook occupancy grid (Thrun, Burgard & Fox): no clamping, so it
//                     adapts ever more slowly, as in the papers' comparisons
//   online            the dynamic grid learning its transitions online (THEORY.md §6)
//   offline           the dynamic grid with transitions learned by offline EM (THEORY.md §5) on
//                     a training run of the same world, then fixed
//   oracle            the dynamic grid with the true transitions: the best any learner can do
//
// ROS-free: standard library only.

#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/cell/offline_em.h"
#include "dynamic_occupancy_grid/evaluation/simulator.h"

namespace dynamic_occupancy_grid {
namespace evaluation {

enum class Method { kStatic, kStaticUnclamped, kOnline, kOffline, kOracle };
constexpr std::array<Method, 5> kAllMethods{Method::kStatic, Method::kStaticUnclamped, Method::kOnline,
                                            Method::kOffline, Method::kOracle};
/// "static", "static_unclamped", "online", "offline", "oracle".
std::string methodName(Method method);

/// The mapper settings of the evaluation for a scenario: its resolution and time step,
/// fixed bounds on the world, everything else the package's defaults.
core::MapperConfig evaluationMapperConfig(const ScenarioConfig& scenario);

/// Offline EM on a training run: the observations of `steps` steps of `training` mapped
/// with `mapper_config`, then Baum–Welch with `em_config` (its initial_p_occ and prior
/// should match the mapper's).
struct OfflineTraining {
  core::ObservationSequences sequences;
  core::OfflineEmResult result;
};
OfflineTraining trainOffline(Simulation& training, const core::MapperConfig& mapper_config, std::int64_t steps,
                             const core::OfflineEmConfig& em_config);
/// The offline EM settings matching `mapper_config` (initial belief, prior transitions,
/// bounds) with the tools' prior weight of 2 pseudo-transitions per from-state.
core::OfflineEmConfig evaluationOfflineEmConfig(const core::MapperConfig& mapper_config);

/// One Mapper per way of learning, all fed the same scans.
class MethodMappers {
 public:
  /// `base` with fixed bounds on `world`: the online mapper learns; the offline and oracle
  /// mappers do not (their transitions are set with setOffline / setOracle; until then, the
  /// prior) and keep unclamped static log-odds for static_unclamped.
  MethodMappers(const core::MapperConfig& base, const World& world);

  /// The offline mapper's transitions: the training result for the cells it has, the prior
  /// for the others.
  void setOffline(const OfflineTraining& training);
  /// The oracle's transitions: the world's true ones for every cell. Call again when the
  /// truth changes (a re-draw).
  void setOracle(const World& world);

  /// Every mapper integrates the scan; the first rejection is thrown as std::runtime_error
  /// (a simulated scan is never invalid).
  void integrate(const core::Scan& scan);
  /// Applies the step being gathered in every mapper: beliefs are then those at its end.
  void finishStep();

  /// p(occ) of cell (x, y) at the end of the last applied step (predicted in closed form for
  /// cells not observed in it), NaN if the method never observed the cell.
  double belief(Method method, std::int32_t x, std::int32_t y) const;
  /// The transitions a dynamic method (online, offline, oracle) uses for cell (x, y), none
  /// if the method never observed the cell. Throws std::invalid_argument for a static method.
  std::optional<core::TransitionParams> transitions(Method method, std::int32_t x, std::int32_t y) const;
  const core::Mapper& mapper(Method method) const;

 private:
  core::Mapper online_;
  core::Mapper offline_;
  core::Mapper oracle_;
};

/// THEORY.md §9: a cell counts as occupied if p(occ) > 0.5, free if < 0.5, otherwise (and
/// if never observed) it is not counted.
struct Accuracy {
  std::size_t correct = 0;
  std::size_t classified = 0;
  double value() const { return classified == 0 ? 0.0 : static_cast<double>(correct) / static_cast<double>(classified); }
};
/// Accuracy of `method` against the true state of the cells of `world` now: every cell, or
/// with `defined` (row-major like World::occupancy) only those where it is non-zero.
Accuracy accuracyOf(const MethodMappers& mappers, Method method, const World& world,
                    const std::vector<std::uint8_t>* defined = nullptr);

/// Mean absolute error of the learned transitions against the truth, over the cells the
/// method observed, separately for dynamic and static cells (static truth = {0, 0}).
struct ParameterError {
  double dynamic_p_occ_given_free = 0.0;
  double dynamic_p_free_given_occ = 0.0;
  std::size_t dynamic_cells = 0;
  double static_p_occ_given_free = 0.0;
  double static_p_free_given_occ = 0.0;
  std::size_t static_cells = 0;
};
ParameterError parameterErrorOf(const MethodMappers& mappers, Method method, const World& world);

/// The accuracy experiment of the papers (Figs. 3–5) on one scenario.
struct AccuracyExperimentConfig {
  int repetitions = 10;
  std::uint64_t seed = 1;  ///< repetition r's world and run seeds are derived from (seed, r)
  unsigned threads = 0;    ///< repetitions run in parallel; 0 = one per core
};
struct AccuracyExperimentResult {
  std::string scenario;
  /// accuracy[method][repetition][step], in kAllMethods order.
  std::array<std::vector<std::vector<double>>, kAllMethods.size()> accuracy;
  /// Per repetition, at the end of the run, for online and offline.
  std::vector<ParameterError> online_error;
  std::vector<ParameterError> offline_error;
  double seconds = 0.0;  ///< wall time
};
/// Runs `repetitions` pairs of (training run, evaluation run) of `scenario`. The training
/// run has the evaluation run's layout (the same dynamic cells, the same bays; no re-draw),
/// its own changes and noise, and the same length; the offline method learns on it. Accuracy is taken after every step over all cells, except
/// in the parking lot: there, as in the paper (whose ground truth for hour i was the grid
/// of run i alone), only over the cells observed since the hour began — the inside of a
/// parked car is never seen, so no map can know it. `progress` (optional) is called after
/// each repetition.
AccuracyExperimentResult runAccuracyExperiment(const ScenarioConfig& scenario, const AccuracyExperimentConfig& config,
                                               const std::function<void(int done)>& progress = {});

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
