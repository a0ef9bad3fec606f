#pragma once
// Navigation with short-term / long-term memory and map hypotheses (Morris et al.,
// "Multiple map hypotheses for planning and navigating in non-stationary environments",
// Algorithms 1-2; THEORY.md §8) against a dynamic occupancy grid and a single static map,
// on the simulator's dividers office (simulator.h, scenarioConfig("dividers")).
//
// Protocol of one repetition. Episodes are divider_period_steps long and start at the
// dividers' moves, so the passages hold still during an episode and change between
// episodes (the paper's dividers, moved between navigation tasks), while people walk all
// the time. The robot shuttles between a and b (DividersLayout), one cell per step
// (4-connected), with the scenario's 360° laser.
//   1. Initial mapping: mapping_episodes episodes driven by an oracle (A* on the true
//      structure, waiting when a person stands in the next cell). Every method maps the same
//      scans; the memory model's updates of this phase build its base map (the paper's
//      separate mapping run; MemoryModelConfig::initial_mapping_updates is set to their
//      number, the last one forced at the end of the phase).
//   2. `episodes` scored episodes. Every method has its own Simulation with the same seeds
//      (the world's dynamics never depend on the robot: the same dividers and people for
//      all). On each step until it arrives, the robot scans, updates its map, plans with
//      A* (planner.h) on its planning grid and moves to the plan's next cell, unless a
//      person stands there (the move fails). The planning grid is the method's map overlaid
//      with the current scan (LiveLayer: the obstacle layer of any navigation stack, which
//      clears the cells its beams cross and marks the cells they end in). A
//      robot that has not arrived when the episode ends failed it and is put on the goal.
//      After arriving it waits for the next episode with the laser off.
//
// Methods:
//   static  the textbook occupancy grid (Method::kStaticUnclamped of evaluation.h): one map
//           that does not model change, as the paper's "single" approach and the static
//           baseline of the path planning experiment. Not the package's clamped static
//           layer: clamping makes it a recency filter that forgets a divider within a few
//           scans, i.e. a (crude) dynamic map, which the HMM grid already represents.
//   hmm     the dynamic occupancy grid learning its transitions online (core::Mapper),
//           its belief predicted to now; p(occ) > 0.5 is blocked.
//   memory  MemoryModel (memory_model.h) with hypothesis planning (HypothesisSelector): A*
//           on each map hypothesis, the robot follows the best-weighted one with a valid plan
//           (Algorithm 2); when its plan runs into cells the current scan sees occupied that
//           the actioned hypothesis holds free (unexpected obstacles), the hypotheses are
//           re-weighted and re-selected (Algorithm 1). Simplified to a known pose: there is
//           no localiser, so the L2-norm of the pose covariance that triggers the paper's
//           switching is replaced by the blocked plan itself, and there is no active/pending
//           split (every hypothesis is planned on when selecting; 2^4 = 16 A* runs at most).
// In all three maps never-observed cells are free (unknown is optimistic).
//
// Metrics (per method, per repetition, then mean and std over repetitions):
//   goal reached      % of scored episodes in which the robot arrived within the episode;
//   path ratio        moves / optimal moves, over the episodes it arrived in; optimal = A* on
//                     the true structure (people left out) at departure;
//   replans           per episode: steps on which the plan being followed became blocked in
//                     the method's planning grid (a divider, a person, a map change);
//   people in LTM     (memory) migrated cells that are not structure at migration time and
//                     that a person stood on during the update's view (target 0), and other
//                     migrated non-structure cells (sensor artefacts); divider cells that
//                     migrated, and the configurations holding them (they should).
//
// ROS-free: standard library only.

#include <array>
#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/memory/memory_model.h"
#include "dynamic_occupancy_grid/evaluation/path_planning.h"
#include "dynamic_occupancy_grid/evaluation/planner.h"
#include "dynamic_occupancy_grid/evaluation/simulator.h"

namespace dynamic_occupancy_grid {
namespace evaluation {

enum class NavigationMethod { kStatic, kHmm, kMemory };
constexpr std::array<NavigationMethod, 3> kAllNavigationMethods{NavigationMethod::kStatic, NavigationMethod::kHmm,
                                                                NavigationMethod::kMemory};
/// "static", "hmm", "memory".
std::string navigationMethodName(NavigationMethod method);

/// What the current scan says, laid over a map for planning: the cells its beams cross are
/// free, the cells its returns end in occupied (over the crossed ones).
struct LiveLayer {
  std::vector<core::CellXY> free;
  std::vector<core::CellXY> occupied;

  /// From a scan on a grid of the world's lattice (cells outside are dropped).
  static LiveLayer fromScan(const core::Scan& scan, double resolution_m, std::int32_t width, std::int32_t height);
  void applyTo(BlockedGrid& grid) const;
};

/// Morris et al.'s hypothesis planning (Algorithms 1-2, simplified to a known pose; see the
/// top of this file). Each hypothesis has a score: its prior weight from the memory
/// (MapHypothesis::weight) times an accumulated factor kept by its set of configurations,
/// so that it survives the memory's updates (a new set starts at 1).
class HypothesisSelector {
 public:
  /// `penalty` in (0, 1] multiplies the actioned hypothesis's factor when its plan is
  /// blocked by an obstacle another hypothesis predicted; `reward` >= 1 multiplies those
  /// hypotheses' factors. Throws std::invalid_argument otherwise.
  HypothesisSelector(double penalty, double reward);

  /// The memory's current hypotheses and their maps (blocked = occupied in the hypothesis),
  /// all of the same size; the actioned one is forgotten (select() again).
  void setHypotheses(std::vector<core::MapHypothesis> hypotheses, std::vector<BlockedGrid> grids);
  std::size_t size() const { return hypotheses_.size(); }
  const core::MapHypothesis& hypothesis(std::size_t h) const { return hypotheses_.at(h); }
  const BlockedGrid& grid(std::size_t h) const { return grids_.at(h); }
  /// Prior weight times the accumulated factor.
  double score(std::size_t h) const;

  /// Algorithm 2: the hypotheses by descending score (ties: their order), the first with a
  /// valid plan from start to goal on its grid overlaid with `live` becomes the actioned one and its plan is returned; if none has one, the best
  /// scored is actioned and the plan is empty. Throws std::logic_error without hypotheses.
  std::vector<core::CellXY> select(core::CellXY start, core::CellXY goal, const LiveLayer& live);
  /// The actioned hypothesis (valid after select()).
  std::size_t actioned() const { return actioned_; }
  /// A* on the actioned hypothesis overlaid with `live`.
  std::vector<core::CellXY> plan(core::CellXY start, core::CellXY goal, const LiveLayer& live);

  /// Algorithm 1: the actioned plan ran into `obstacles` (cells it holds free, now seen
  /// occupied). If any other hypothesis predicted one of them (holds it occupied), the
  /// actioned hypothesis is penalised and those are rewarded, and true is returned; an
  /// obstacle no hypothesis predicted (a person, a divider never seen there) says nothing
  /// about which map is right and changes nothing.
  bool reportObstacles(const std::vector<core::CellXY>& obstacles);

 private:
  double& factor(std::size_t h);

  double penalty_;
  double reward_;
  std::vector<core::MapHypothesis> hypotheses_;
  std::vector<BlockedGrid> grids_;
  std::map<std::vector<std::uint32_t>, double> factors_;
  std::size_t actioned_ = 0;
  AStarPlanner planner_;
};

struct MemoryExperimentConfig {
  int repetitions = 10;
  int mapping_episodes = 2;  ///< oracle-driven initial mapping (a -> b -> a ...)
  int episodes = 20;         ///< scored, alternating directions
  /// The memory model's settings; resolution and origin are the scenario's, and
  /// initial_mapping_updates is set by the protocol (the mapping phase's updates). Views of
  /// 3 m (15 steps), not the default 1 m: Morris et al. register a whole navigation run into
  /// one view; with shorter views a cell people cross again and again (a passage) is hit in
  /// consecutive views now and then. Person cells in LTM over 10 repetitions (seed 1):
  /// 15 with 1 m views, 1 with 2 m, 0 with 2.5 m (but 1 with seed 3), 0 with 3 m (seeds
  /// 1-4, 40 repetitions), while 100-150 divider cells migrate in every setting.
  core::MemoryModelConfig memory = [] {
    core::MemoryModelConfig c;
    c.update_distance_m = 3.0;
    return c;
  }();
  double penalty = 0.1;  ///< HypothesisSelector
  double reward = 10.0;
  std::uint64_t seed = 1;  ///< repetition r's seeds are derived from (seed, r)
  unsigned threads = 0;    ///< repetitions run in parallel; 0 = one per core; results do not depend on it

  /// Throws std::invalid_argument naming the first bad field.
  void validate() const;
};

struct EpisodeRecord {
  bool reached = false;
  std::int64_t moves = 0;    ///< cells moved (also when it failed)
  std::int64_t optimal = 0;  ///< optimal moves at departure
  int replans = 0;
};

struct MemoryRepetition {
  /// episodes[m][e]: method kAllNavigationMethods[m], scored episode e.
  std::array<std::vector<EpisodeRecord>, kAllNavigationMethods.size()> episodes;
  std::int64_t memory_updates = 0;          ///< of the memory robot, mapping phase included
  std::size_t configurations = 0;           ///< created after the base map
  std::size_t people_in_ltm = 0;            ///< migrated cells a person stood on, not structure
  std::size_t other_non_structure_in_ltm = 0;
  std::size_t divider_cells_in_ltm = 0;     ///< migrated cells of closed dividers
  std::size_t divider_configurations = 0;   ///< configurations holding divider cells
  std::int64_t divider_moves = 0;           ///< passages that changed state between scored episodes
  int hypothesis_switches = 0;              ///< re-weightings that changed the actioned hypothesis
};

struct MemoryExperimentResult {
  std::vector<MemoryRepetition> repetitions;
  double seconds = 0.0;  ///< wall time

  /// Per repetition, then mean and std over repetitions.
  MeanStd goalReachedPercent(NavigationMethod method) const;
  MeanStd pathRatio(NavigationMethod method) const;  ///< over reached episodes
  MeanStd replansPerEpisode(NavigationMethod method) const;
  MeanStd perRepetition(const std::function<double(const MemoryRepetition&)>& value) const;
};

/// Runs the experiment on `dividers` (a ScenarioConfig of kind kDividers). `progress`
/// (optional) is called after each repetition. Throws std::invalid_argument for a bad
/// configuration or another scenario kind.
MemoryExperimentResult runMemoryExperiment(const ScenarioConfig& dividers, const MemoryExperimentConfig& config,
                                           const std::function<void(int done)>& progress = {});

/// A Markdown table: one row per method (goal reached, path ratio, replans per episode),
/// then the memory's LTM counts.
std::string formatMemoryTable(const MemoryExperimentResult& result);

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
