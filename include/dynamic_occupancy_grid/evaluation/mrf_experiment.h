#pragma once
// The simulation of Li, Barão & Rato (Sec. IV; THEORY.md §7) as a measurement: on the
// scenario "mrf_squares" (simulator.h), offline EM of the transition maps without and with
// the MRF prior, each scored against the world's true transitions by RMSE, separately on
// sparsely and on well observed cells, with the EM's wall time and the MRF's work per EM
// iteration.
//
// ROS-free: standard library only.

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <vector>

#include "dynamic_occupancy_grid/core/offline_em.h"
#include "dynamic_occupancy_grid/evaluation/simulator.h"

namespace dynamic_occupancy_grid {
namespace core {

/// Root mean squared error of learned transitions against the truth over a set of cells.
struct TransitionRmse {
  double p_occ_given_free = 0.0;
  double p_free_given_occ = 0.0;
  std::size_t cells = 0;  ///< 0: no cell in the set, both errors 0
};

/// The RMSE over the cells with fewer than `sparse_below` observed steps and over the others.
struct SplitRmse {
  TransitionRmse sparse;
  TransitionRmse well_observed;
};

/// RMSE of `learned` (one entry per cell of `sequences`, in its order) against
/// world.truth(x, y), split by the number of observed steps of each cell (end - begin).
/// Throws std::invalid_argument if the sizes differ or a cell lies outside the world.
SplitRmse transitionRmse(const ObservationSequences& sequences, const std::vector<TransitionParams>& learned,
                         const World& world, std::size_t sparse_below);

/// What a cell of the world is, for scoring by kind: its parameters are identifiable from
/// its data only where both states occur. A static free cell is never occupied, so its
/// p_free_given_occ is not (its learned value is the prior's and the chain start's); a static
/// occupied cell's p_occ_given_free likewise.
enum class CellKind { kStaticFree = 0, kStaticOccupied = 1, kChanging = 2 };
constexpr std::size_t kCellKinds = 3;
/// kChanging where world.truth(x, y) is not {0, 0}, else the static cell's state.
CellKind cellKind(const World& world, std::int32_t x, std::int32_t y);
/// Short names: "static_free", "static_occupied", "changing".
const char* cellKindName(CellKind kind);

/// transitionRmse over the cells of each kind separately (index: CellKind).
std::array<SplitRmse, kCellKinds> transitionRmseByKind(const ObservationSequences& sequences,
                                                        const std::vector<TransitionParams>& learned,
                                                        const World& world, std::size_t sparse_below);

struct MrfExperimentConfig {
  int repetitions = 10;
  std::uint64_t seed = 1;   ///< repetition r's seeds are derived from (seed, r)
  unsigned threads = 0;     ///< repetitions run in parallel; 0 = one per core
  double temperature = 50.0;  ///< the MRF's T (the paper's value)
  std::size_t sparse_below = 10;  ///< cells with fewer observed steps are "sparse"
  /// EM iterations at most, both EMs (the paper's 300: started at 0.5, EM is still moving
  /// after the tools' default of 100).
  int max_iterations = 300;

  /// Throws std::invalid_argument naming the first bad field.
  void validate() const;
};

/// One EM (plain or with the MRF) on one run.
struct MrfEmOutcome {
  SplitRmse rmse;
  std::array<SplitRmse, kCellKinds> rmse_by_kind;  ///< the same per CellKind
  double em_seconds = 0.0;   ///< wall time of runOfflineEm (single-threaded)
  int em_iterations = 0;     ///< M-steps (plain EM: the most any cell used)
  std::vector<double> objective;  ///< OfflineEmResult::objective
  /// Per M-step, Newton iterations on p(occ -> occ) and p(free -> free); empty for plain EM.
  std::vector<std::array<int, 2>> newton_iterations;
};

struct MrfRepetition {
  std::uint64_t world_seed = 0;
  std::uint64_t run_seed = 0;
  std::size_t cells_observed = 0;
  MrfEmOutcome plain;
  MrfEmOutcome mrf;
};

/// Maps of one run for plotting, row-major over the world (World::index); NaN where a map
/// has no value (learned values of cells never observed).
struct MrfMaps {
  std::int32_t width = 0;
  std::int32_t height = 0;
  std::vector<std::uint32_t> observed_steps;  ///< 0 for cells never observed
  std::vector<TransitionParams> truth;
  std::vector<TransitionParams> plain;
  std::vector<TransitionParams> mrf;
};

struct MrfExperimentResult {
  std::vector<MrfRepetition> repetitions;
  MrfMaps first_maps;      ///< of repetition 0
  double seconds = 0.0;    ///< wall time of the whole experiment
};

/// Runs `config.repetitions` runs of `scenario` (normally scenarioConfig("mrf_squares")):
/// each records its observations with a Mapper of evaluationMapperConfig(scenario), then
/// runs offline EM with evaluationOfflineEmConfig (the tools' prior), initial parameters 0.5
/// (the paper's) and config.max_iterations, once plain and once with mrf_temperature =
/// config.temperature, and scores
/// both against the truth. Results do not depend on the number of threads (the timings
/// aside). `progress` (optional) is called after each repetition.
MrfExperimentResult runMrfExperiment(const ScenarioConfig& scenario, const MrfExperimentConfig& config,
                                     const std::function<void(int done)>& progress = {});

}  // namespace core
}  // namespace dynamic_occupancy_grid
