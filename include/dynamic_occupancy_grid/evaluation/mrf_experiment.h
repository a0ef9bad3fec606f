#pragma once
// The simulation of Li, Barão & Rato (Sec. IV; THEORY.md §7) as a measurement: on the
// scenario "mrf_squares" (simulator.h), offline EM of the transition maps without and with
// the MRF prior, and two online learners of core::Mapper on the same scans, each scored
// against the world's true transitions by RMSE per kind of cell on the parameters the
// cell's data carry, separately on sparsely and on well observed cells, with the EM's wall
// time and the MRF's work per EM iteration. The online learners: each cell's own online EM,
// and the package's default learner, kinds of cells (TransitionLearner::kKinds). Two ways
// to borrow strength from other cells: the MRF from a cell's neighbours, the kinds from the
// cells of the same (learned, hidden) kind.
//
// ROS-free: standard library only.

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <vector>

#include "dynamic_occupancy_grid/core/cell/offline_em.h"
#include "dynamic_occupancy_grid/evaluation/simulator.h"

namespace dynamic_occupancy_grid {
namespace evaluation {

/// Root mean squared error of learned transitions against the truth over a set of cells.
struct TransitionRmse {
  double p_occ_given_free = 0.0;  ///< NaN: not scored (transitionRmseByKind)
  double p_free_given_occ = 0.0;  ///< NaN: not scored (transitionRmseByKind)
  std::size_t cells = 0;  ///< 0: no cell in the set, both errors 0 (or NaN where not scored)
};

/// The RMSE over the cells with fewer than `sparse_below` observed steps and over the others.
struct SplitRmse {
  TransitionRmse sparse;
  TransitionRmse well_observed;
};

/// RMSE of `learned` (one entry per cell of `sequences`, in its order) against
/// world.truth(x, y), split by the number of observed steps of each cell (end - begin).
/// Throws std::invalid_argument if the sizes differ or a cell lies outside the world.
SplitRmse transitionRmse(const core::ObservationSequences& sequences,
                         const std::vector<core::TransitionParams>& learned, const World& world,
                         std::size_t sparse_below);

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

/// Whether a cell of `kind` carries p_occ_given_free (`occ_given_free`) or p_free_given_occ
/// in its data, i.e. whether it is scored: a changing cell both, a static free cell only
/// p_occ_given_free (it is free, and stays so), a static occupied cell only p_free_given_occ.
bool isScored(CellKind kind, bool occ_given_free);

/// transitionRmse over the cells of each kind separately (index: CellKind), on the
/// parameters isScored gives the kind: the other one is NaN (a static free cell's
/// p_free_given_occ is the prior's and the chain start's, whatever the learner).
std::array<SplitRmse, kCellKinds> transitionRmseByKind(const core::ObservationSequences& sequences,
                                                        const std::vector<core::TransitionParams>& learned,
                                                        const World& world, std::size_t sparse_below);

/// The changing cells by what their data show: [0] those seen in both states (a step of more
/// hits than misses and one of more misses than hits), [1] the others (in the squares: the
/// cells behind the front face, observed only while the square is free), each split as
/// transitionRmse, both parameters scored.
std::array<SplitRmse, 2> changingRmseBySeenStates(const core::ObservationSequences& sequences,
                                                  const std::vector<core::TransitionParams>& learned,
                                                  const World& world, std::size_t sparse_below);

/// Per square of the mrf_squares scenario (MrfSquaresLayout order): how many of its cells
/// `sequences` show in both states, with at least one step of more hits than misses and
/// one of more misses than hits.
std::array<std::size_t, 4> squareCellsSeenInBothStates(const core::ObservationSequences& sequences,
                                                       const MrfSquaresLayout& layout);

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
  std::array<SplitRmse, 2> rmse_changing_by_data;  ///< changingRmseBySeenStates
  double em_seconds = 0.0;   ///< wall time of runOfflineEm (single-threaded)
  int em_iterations = 0;     ///< M-steps (plain EM: the most any cell used)
  std::vector<double> objective;  ///< OfflineEmResult::objective
  /// Per M-step, Newton iterations on p(occ -> occ) and p(free -> free); empty for plain EM.
  std::vector<std::array<int, 2>> newton_iterations;
};

/// One kind of cells as the kinds learner ended a run with (CellKinds::transitions, weight).
struct MrfLearnedKind {
  core::TransitionParams transitions;
  double weight = 0.0;  ///< the kind's share of the cells
};

/// One online learner (core::Mapper learning while it maps the run's scans) on one run:
/// each cell's transitions at the end, the two its cell publishes (learner kCellEm: its
/// filter's, the prior until OnlineEmConfig::min_observed_steps observed steps, so sparse
/// cells are scored on the prior they were given; learner kKinds: the summary of its kind
/// posterior after its last observed step).
struct MrfOnlineOutcome {
  SplitRmse rmse;
  std::array<SplitRmse, kCellKinds> rmse_by_kind;
  std::array<SplitRmse, 2> rmse_changing_by_data;  ///< changingRmseBySeenStates
  /// learner kKinds: the kinds after the last step (Mapper::kinds(), in its order); empty
  /// for kCellEm.
  std::vector<MrfLearnedKind> kinds;
  double seconds = 0.0;           ///< wall time of the mapper's integrate and finishStep calls
};

struct MrfRepetition {
  std::uint64_t world_seed = 0;
  std::uint64_t run_seed = 0;
  std::size_t cells_observed = 0;
  /// Per square, its cells observed in both states (squareCellsSeenInBothStates).
  std::array<std::size_t, 4> square_cells_both_states{};
  MrfEmOutcome plain;
  MrfEmOutcome mrf;
  /// learner kCellEm: every cell starts from prior_transitions.
  MrfOnlineOutcome online;
  /// learner kKinds (the package's default): kinds of cells, a hierarchical prior.
  MrfOnlineOutcome online_kinds;
};

/// Maps of one run for plotting, row-major over the world (World::index); NaN where a map
/// has no value (learned values of cells never observed).
struct MrfMaps {
  std::int32_t width = 0;
  std::int32_t height = 0;
  std::vector<std::uint32_t> observed_steps;  ///< 0 for cells never observed
  std::vector<core::TransitionParams> truth;
  std::vector<core::TransitionParams> plain;
  std::vector<core::TransitionParams> mrf;
  std::vector<core::TransitionParams> online;
  std::vector<core::TransitionParams> online_kinds;
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
/// config.temperature. The same scans are mapped by two online learners, Mappers of
/// evaluationMapperConfig(scenario) with the package's online-learning defaults (same
/// sensor model, prior_transitions as the guess) but the learner: kCellEm and kKinds. All
/// four are scored against the truth. Results do not
/// depend on the number of threads (the timings aside). `progress` (optional) is called
/// after each repetition.
MrfExperimentResult runMrfExperiment(const ScenarioConfig& scenario, const MrfExperimentConfig& config,
                                     const std::function<void(int done)>& progress = {});

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
