#pragma once
// Murphy's 2D world with doors (K. P. Murphy, "Bayesian map learning in dynamic
// environments", NIPS 1999, Fig. 1(c) and the end of Section 4): a grid of walls, free space
// and doors that open and close, a robot that slips and sees noisily, the RBPF of Section 4
// (particles sample the robot's cell; each carries every cell's HMM belief) and actions
// chosen for the expected discounted reward of visiting cells,
//   r(i) = H(L) (1 - H(M(i))) + (1 - H(L)) H(M(i)),
// H the normalised entropy: a lost robot goes where the map is certain, a localised one where
// it is not. Murphy reports that "after learning the map, the robot spends its time visiting
// each of the doors, to keep its knowledge of their state up-to-date"; runDoorsWorld measures
// that against a robot that moves at random (docs/murphy_corridor.md, "The 2D world with
// doors").
//
// Where the paper is silent or too brief to follow, choices made here:
// - cells are binary HMMs in the core's terms: walls and closed doors occupied, free space
//   and open doors free (Murphy's four labels are these two states of three kinds of cell);
// - the robot sees its four neighbours (each reading right with p_o), not its own cell: a
//   robot never stands on a wall, so its own cell would never show one;
// - a move into an occupied cell fails (the map changes where the robot can go: the
//   restriction Murphy lifts in 2D). The proposal is his optimal one: a slip, a blocked move
//   and a move, each weighed by its prior under the particle's map and by the readings'
//   likelihood from where it leaves the robot; the target then holds what was drawn;
// - transitions are known (his Section 3 assumption): doors change with p_c both ways, walls
//   and free space never; the map's states are learned, from an unknown (p = 0.5) start,
//   the grid's edge known to be wall (as the corridor's ends are);
// - the policy: value iteration on the mixture map (cells with p(occ) < 0.5 passable); the
//   reward of a cell is that of the four cells seen from it; H(L) is normalised by log 10
//   (capped at 1: a cloud over ten cells is lost), not by log of the grid's cells; the action
//   maximises the value averaged over the particles' cells (QMDP), and one step in ten is
//   random (a robot that took one place for another otherwise pushes at a wall for ever, its
//   beliefs unchanged).
//
// ROS-free: standard library and the core only.

#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "dynamic_occupancy_grid/evaluation/murphy_corridor.h"

namespace dynamic_occupancy_grid {
namespace evaluation {

enum class DoorsCell : std::uint8_t { kFree = 0, kWall = 1, kDoor = 2 };

/// The world's layout: cells row by row (index y * width + x), the robot's start.
struct DoorsLayout {
  int width = 0;
  int height = 0;
  std::vector<DoorsCell> cells;
  int start = 0;  ///< a free cell
  DoorsCell at(int x, int y) const { return cells[static_cast<std::size_t>(y * width + x)]; }
  /// Throws std::invalid_argument unless the border is wall, the start free and the sizes
  /// agree.
  void validate() const;
};

/// Four rooms of different sizes with pillars, a door between each two neighbours, 15 x 11
/// cells (the paper's figure is not in our copy; its caption: walls, free space, open and
/// closed doors).
DoorsLayout murphyDoorsLayout();

enum class DoorsPolicy : std::uint8_t { kEntropy = 0, kRandom = 1 };
const char* doorsPolicyName(DoorsPolicy policy);  ///< "entropy", "random"

struct DoorsWorldConfig {
  /// p_a: a move succeeds (into a free cell); else the robot stays. 0.9, not the corridor's
  /// 0.8: with a slip in five steps and a map learned from nothing, the particles lose the
  /// robot in most runs of either policy (docs/murphy_corridor.md).
  double p_action = 0.9;
  double p_observation = 0.9;  ///< p_o: each neighbour read right (< 1)
  double p_change = 0.02;      ///< p_c: a door opens or closes per step
  int particles = 400;
  double resample_below = 0.5;  ///< resample when N_eff < this * particles
  double discount = 0.9;        ///< of the policy's value iteration
  int steps = 2000;
  std::uint64_t seed = 1;
  /// Throws std::invalid_argument naming the first bad field.
  void validate() const;
};

/// One run of one policy.
struct DoorsRun {
  DoorsPolicy policy = DoorsPolicy::kEntropy;
  /// Second half of the run, mean over its steps and the doors: the mixture map says the
  /// door's true state (p(occ) > 0.5 for closed).
  double door_accuracy = 0.0;
  /// Second half, mean over its steps and the doors: steps since the robot last saw the door.
  double door_staleness_steps = 0.0;
  /// Share of the steps the robot stood next to a door.
  double near_door_share = 0.0;
  /// Mean over steps of the particles' probability of the robot's true cell.
  double localisation = 0.0;
  /// At the end: walls and free cells whose mixture p(occ) is on their side of 0.5.
  double static_accuracy = 0.0;
  std::vector<std::uint32_t> visits;  ///< steps the robot stood on each cell
  std::vector<double> final_map;      ///< the mixture p(occ) per cell at the end
};

/// One run: the world and the robot drawn from config.seed (the same world for both
/// policies; the robot's draws differ once the actions do).
DoorsRun runDoorsWorld(const DoorsLayout& layout, const DoorsWorldConfig& config, DoorsPolicy policy);

struct DoorsExperimentConfig {
  DoorsWorldConfig world;
  int runs = 10;           ///< seeds seed, seed + 1, ...
  unsigned threads = 0;    ///< runs in parallel; 0 = one per core
};

struct DoorsExperimentResult {
  DoorsLayout layout;
  std::vector<DoorsRun> entropy;  ///< per run
  std::vector<DoorsRun> random;
  double seconds = 0.0;
};

DoorsExperimentResult runDoorsExperiment(const DoorsExperimentConfig& config);

/// murphy_doors_runs.csv (a row per run and policy) and murphy_doors_maps.csv (per cell:
/// the layout, and each policy's visits and final map in a typical run: the one whose
/// entropy-driven robot has the lower median door accuracy).
std::vector<std::pair<std::string, std::string>> doorsCsvTables(const DoorsExperimentResult& result);

/// The summary.md section; appends the experiment's target ("the entropy policy keeps the
/// doors more current than a random walk") to `targets`.
std::string formatDoorsSummary(const DoorsExperimentConfig& config, const DoorsExperimentResult& result,
                               std::vector<MurphyTarget>* targets);

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
