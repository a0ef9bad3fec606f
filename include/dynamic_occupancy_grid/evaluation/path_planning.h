#pragma once
// The path planning experiment of Meyer-Delius et al. (AAAI 2012, section "Path Planning",
// Table 1) on the simulator's door scenario (simulator.h, scenarioConfig("door")): a robot
// shuttles between A and B; the short path goes through a door that opens and closes at
// random, the long path goes round. Policies that plan on different maps are compared by
// how often they choose the path that was best in hindsight.
//
// Protocol of one repetition (every policy has its own Simulation with the same seeds, so
// the world and the door's changes are the same for all; the door changes from its own
// random stream, so its trajectory does not depend on what a robot does):
//
//   1. Exploration: exploration_steps steps of the scripted loop (A -> the cell west of the
//      door -> A -> long path -> B -> the cell east of the door -> B -> long path -> A, one
//      cell per step, never through the door). Every policy's MethodMappers integrates the
//      same scans (its a-priori map; the online mapper learns). The offline method runs
//      offline EM (trainOffline) on the observations of this run and keeps the learned
//      transitions fixed from then on (until then it filters with the prior's); the oracle
//      has the true ones from the start.
//   2. `runs` runs, alternating A -> B and B -> A, from A. Before every run the robot is
//      parked at its start for idle_steps steps with the laser off: the world goes on, the
//      mappers see nothing (the HMM predicts the door in closed form over the gap). During a
//      run, on every step, the robot scans (fed to its mappers, then finishStep()), decides
//      its next cell with A* (planner.h) and moves one cell (4-connected); a move into a
//      cell that is occupied in truth fails (the robot stays and re-plans next step). A run
//      ends when the robot stands on the goal; one that takes max_run_steps steps is a
//      timeout and the robot is put on the goal.
//
// Policies:
//   static   A* on the textbook occupancy grid (Method::kStaticUnclamped; the paper's
//            baseline, Thrun, Burgard & Fox): a cell is blocked if its p(occ) > 0.5,
//            never-observed cells are free. Not the package's clamped static layer: in this
//            scenario the free cells of the 1-cell corridors now and then get a hit (beams
//            ending on a wall face 0.25 m from the laser; range noise moves the end point
//            across the cell boundary), and the clamped layer, which follows the last few
//            observations of a cell, then blocks a corridor cell the robot no longer sees, so
//            that no path is left (measured: 53 % of its runs timed out).
//   online   the same on the online-learning dynamic map's belief.
//   offline  the same on the offline-EM dynamic map's belief.
//   random   at departure picks the short or the long path with probability 1/2 and
//            commits; on the short path, once it finds the door closed it takes the long one.
//   optimal  knows the door's true transitions and holds the oracle map's filtered belief of
//            the door; at departure it takes the short path if its expected time is lower:
//            short if the door is open when the robot gets there, otherwise the time to the
//            point where it sees the door closed, back, and the long path. Falls back to the
//            long path when it finds the door closed.
//   random and optimal move by A* on the oracle map with the door cell set by their choice
//   (blocked on the long path, free on the short one until found closed). "Found closed"
//   means: the door was observed during this run and the oracle map's p(occ) of it is then
//   > 0.5: the same perception (laser, map, threshold) as the map-based policies.
//
// Classes, judged in hindsight from the door's recorded states (RunClass, classifyRun).
// Effectiveness = short + long: the share of runs on the path that was best in hindsight.
//
// What the maps can do here: with the scenario's symmetric door (p_of = p_fo) the door's
// stationary p(occ) is exactly the 0.5 of the blocked test, so a map with the true
// transitions predicts an unobserved door towards 0.5 from the side it was last seen on and
// never across: planning on it acts like planning on a static map. A learned map differs
// where its estimates are asymmetric (offline EM's stationary p(occ) is about the share of
// the exploration the door spent closed): a door seen closed is free again after a while
// when that share was below 1/2.
//
// ROS-free: standard library only.

#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/cell/cell_model.h"
#include "dynamic_occupancy_grid/evaluation/simulator.h"

namespace dynamic_occupancy_grid {
namespace evaluation {

enum class Policy { kStatic, kOnline, kOffline, kRandom, kOptimal };
constexpr std::array<Policy, 5> kAllPolicies{Policy::kStatic, Policy::kOnline, Policy::kOffline, Policy::kRandom,
                                             Policy::kOptimal};
/// "static", "online", "offline", "random", "optimal" (Table 1's columns).
std::string policyName(Policy policy);

/// Table 1's rows, plus timeouts (a run that never arrived; not in the paper).
enum class RunClass {
  kShort,                    ///< went through the door
  kLong,                     ///< took the long path directly; going through the door (waiting
                             ///< for it if closed) would not have been faster
  kIndirectLong,             ///< tried the short path, turned back, took the long path; waiting
                             ///< at the door would not have been faster
  kUnnecessaryIndirectLong,  ///< the same, but waiting at the door would have been faster
  kUnnecessaryDirectLong,    ///< took the long path directly; going through the door (waiting
                             ///< for it if closed) would have been faster
  kTimeout,
};
constexpr std::array<RunClass, 6> kAllRunClasses{RunClass::kShort,
                                                 RunClass::kLong,
                                                 RunClass::kIndirectLong,
                                                 RunClass::kUnnecessaryIndirectLong,
                                                 RunClass::kUnnecessaryDirectLong,
                                                 RunClass::kTimeout};
/// "short", "long", "indirect long", "unnecessary indirect long", "unnecessary direct long",
/// "timeout".
std::string runClassName(RunClass run_class);

/// The geometry of one run along the short path, in cells (moves) from its start.
struct RunGeometry {
  std::int32_t door_progress = 0;     ///< the door's cell
  std::int32_t short_path_cells = 0;  ///< the goal, through the door
  std::int32_t long_path_cells = 0;   ///< moves of the long path
};

/// Where a robot that tried the short path gave it up: it stood `progress` cells along
/// the short path (0 = the start, < the door) at step `step` and moved back.
struct ShortPathTurn {
  std::int32_t progress = 0;
  std::int64_t step = 0;
};

/// What a run did, as far as the classification needs it. The robot stands at its start
/// at departure_step; a move decided at step t has it in the next cell at step t + 1.
struct RunTrace {
  std::int64_t departure_step = 0;
  bool passed_door = false;
  /// The first time it moved back along the short path, if it did (it tried that path).
  std::optional<ShortPathTurn> turn;
  bool timed_out = false;
};

/// The class of a run in hindsight. `door_open[t]` = the door is open at step t; a robot in
/// the cell before the door can move into it at step t iff door_open[t].
///   - timed out: kTimeout; through the door: kShort;
///   - otherwise the long path is compared with going through the door, waiting at it if
///     needed (walk to the cell before it, enter at the first open step s, arrive at
///     s + 1 + short_path_cells - door_progress); waiting was better iff that is strictly
///     earlier than the long path's arrival. Both kinds of long run are judged by this rule:
///   - long path without a turn: the long path arrives at departure + long_path_cells, the
///     door can be entered from s >= departure + door_progress - 1: kUnnecessaryDirectLong
///     if waiting was better, else kLong;
///   - turned back at (k, t): the detour arrives at t + k + long_path_cells, the door can be
///     entered from s >= t + door_progress - 1 - k: kUnnecessaryIndirectLong if waiting was
///     better, else kIndirectLong.
/// Throws std::out_of_range if door_open does not reach the steps the decision needs
/// (up to the long path's arrival).
RunClass classifyRun(const RunTrace& trace, const RunGeometry& geometry, const std::vector<std::uint8_t>& door_open);

struct PathPlanningConfig {
  int repetitions = 20;  ///< as in the paper
  int runs = 20;         ///< per repetition, as in the paper
  /// Steps of the scripted exploration loop (152 steps per loop; a multiple of it ends at A,
  /// where the first run starts; otherwise the robot is put there). 132 loops: about 20
  /// door changes at p = 0.001 per step, so that offline EM learns each of the door's two
  /// rates from about 10 events (relative error about 1/sqrt(10), 30 %).
  std::int64_t exploration_steps = 132 * 152;
  /// Parked steps (laser off) before every run. One relaxation time of the door,
  /// 1 / (p_of + p_fo) = 500 steps at p = 0.001: the correlation with the door's state at
  /// the last sighting has decayed to 1/e, so the state at decision time is far from certain
  /// (as in the paper, where even the optimal policy was right in only 57.75 % of the runs)
  /// but still informative.
  std::int64_t idle_steps = 500;
  /// A run taking this many steps is a timeout (10 times the long path: the robot is stuck).
  std::int64_t max_run_steps = 510;
  std::uint64_t seed = 1;  ///< repetition r's seeds are derived from (seed, r)
  unsigned threads = 0;    ///< repetitions run in parallel; 0 = one per core; results do not depend on it
  std::vector<Policy> policies{kAllPolicies.begin(), kAllPolicies.end()};  ///< which to run

  /// Throws std::invalid_argument naming the first bad field.
  void validate() const;
};

/// One run of one policy.
struct RunRecord {
  bool from_a = true;
  std::int64_t steps = 0;  ///< from departure to arrival (max_run_steps for a timeout)
  RunTrace trace;
  RunClass run_class = RunClass::kShort;
};

/// What the exploration of one repetition gave (the same for every policy).
struct ExplorationSummary {
  std::int64_t door_changes = 0;          ///< true changes of the door during exploration
  double door_open_fraction = 0.0;        ///< of the exploration's steps
  core::TransitionParams offline_door;          ///< the door's transitions learned by offline EM
  core::TransitionParams online_door;           ///< the online mapper's at the end of exploration
};

struct MeanStd {
  double mean = 0.0;
  double std = 0.0;  ///< sample standard deviation (n - 1), 0 for one value
};
/// Mean and sample standard deviation of `values` (both 0 for none).
MeanStd meanStd(const std::vector<double>& values);

struct PathPlanningResult {
  std::vector<Policy> policies;  ///< as in the config
  /// runs[p][r][i]: policy policies[p], repetition r, run i.
  std::vector<std::vector<std::vector<RunRecord>>> runs;
  std::vector<ExplorationSummary> exploration;  ///< per repetition
  double seconds = 0.0;                         ///< wall time

  /// Percentage of a repetition's runs in `run_class`, mean and std over repetitions.
  /// Throws std::invalid_argument for a policy that was not run.
  MeanStd classPercent(Policy policy, RunClass run_class) const;
  /// Percentage of short + long runs, mean and std over repetitions.
  MeanStd effectiveness(Policy policy) const;
};

/// Runs the experiment on `door` (a ScenarioConfig of kind kDoor). `progress` (optional) is
/// called after each repetition with the number done. Throws std::invalid_argument for a bad
/// configuration or another scenario kind.
PathPlanningResult runPathPlanningExperiment(const ScenarioConfig& door, const PathPlanningConfig& config,
                                             const std::function<void(int done)>& progress = {});

/// Table 1 of the paper (percent of runs, mean and std over 20 repetitions); std::nullopt
/// where it has no value: timeouts, and static's "unnecessary indirect long", which is
/// illegible in our copy of the text (the column summing to 100 % puts it at 0.25).
std::optional<MeanStd> paperTable1(Policy policy, RunClass run_class);
/// Table 1's effectiveness row.
MeanStd paperEffectiveness(Policy policy);

/// Our result next to the paper's, one row per class plus effectiveness, one column per
/// policy run: "ours mean ± std (paper mean ± std)".
std::string formatPathPlanningTable(const PathPlanningResult& result);

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
