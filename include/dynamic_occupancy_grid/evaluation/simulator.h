#pragma once
// A simulator of changing worlds for the evaluation (and for tests): a grid of static and
// dynamic cells, each dynamic cell a 2-state Markov chain with its own true transition
// probabilities (THEORY.md §1), a robot driving a scripted path, and a 2D laser cast
// against the true state of the cells. The true state of every cell at every step is
// available next to the scans, which is what the accuracy of THEORY.md §9 needs.
//
// World cell (x, y) is the square [x r, (x + 1) r) x [y r, (y + 1) r) in metres (r the
// resolution): the lattice of a Mapper with origin (0, 0) and the same resolution.
//
// All randomness comes from Rng (xoshiro256**), seeded explicitly: a run is reproducible
// on any platform. ROS-free: standard library only.

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/cell/cell_model.h"
#include "dynamic_occupancy_grid/core/pose/motion_model.h"
#include "dynamic_occupancy_grid/core/grid/scan.h"
#include "dynamic_occupancy_grid/core/grid/traversal.h"

namespace dynamic_occupancy_grid {
namespace evaluation {

/// xoshiro256** seeded through splitmix64: the same numbers on every platform (unlike the
/// standard library's distributions).
class Rng {
 public:
  explicit Rng(std::uint64_t seed);
  std::uint64_t next();
  /// Uniform in [0, 1), 53 random bits.
  double uniform();
  /// True with probability p.
  bool bernoulli(double p) { return uniform() < p; }
  /// Standard normal (Box–Muller).
  double normal();
  /// Uniform integer in [0, n), n > 0 (rejection: no modulo bias).
  std::uint64_t below(std::uint64_t n);

 private:
  std::array<std::uint64_t, 4> state_;
};

/// Scrambles a seed (splitmix64's output function), so that seeds derived from nearby
/// inputs (seed, repetition) are unrelated.
std::uint64_t mixSeed(std::uint64_t x);

/// The true world: every cell's state now, and its true per-step transition probabilities.
class World {
 public:
  /// All cells static and free. Throws std::invalid_argument for a non-positive size or
  /// resolution.
  World(std::int32_t width, std::int32_t height, double resolution_m);

  std::int32_t width() const { return width_; }
  std::int32_t height() const { return height_; }
  double resolution() const { return resolution_m_; }
  bool inside(std::int32_t x, std::int32_t y) const { return x >= 0 && y >= 0 && x < width_ && y < height_; }
  std::size_t index(std::int32_t x, std::int32_t y) const {
    return static_cast<std::size_t>(y) * static_cast<std::size_t>(width_) + static_cast<std::size_t>(x);
  }
  core::CellXY cellOf(std::size_t index) const {
    return core::CellXY{static_cast<std::int32_t>(index % static_cast<std::size_t>(width_)),
                  static_cast<std::int32_t>(index / static_cast<std::size_t>(width_))};
  }

  /// State now; cells outside the world are free.
  bool occupied(std::int32_t x, std::int32_t y) const { return inside(x, y) && occupancy_[index(x, y)] != 0; }
  /// True transition probabilities per step ({0, 0} for a static cell).
  core::TransitionParams truth(std::int32_t x, std::int32_t y) const { return truth_[index(x, y)]; }
  /// Whether step() changes the cell at random (with truth(x, y)).
  bool isDynamic(std::int32_t x, std::int32_t y) const { return random_[index(x, y)] != 0; }

  /// A static cell (never changes by itself; truth {0, 0}).
  void setStatic(std::int32_t x, std::int32_t y, bool occupied);
  /// A cell that step() changes at random with `truth`, starting in state `occupied`.
  void setDynamic(std::int32_t x, std::int32_t y, const core::TransitionParams& truth, bool occupied);
  /// A cell changed by scheduled events only (parking bays), whose true parameters are the
  /// per-step Markov rates of those events: step() leaves it alone.
  void setScheduled(std::int32_t x, std::int32_t y, const core::TransitionParams& truth, bool occupied);
  /// Changes the state of a cell now (an event), keeping its kind and truth.
  void setState(std::int32_t x, std::int32_t y, bool occupied);

  /// One step of the random dynamics: each dynamic cell changes state with its probability.
  void step(Rng& rng);

  /// State of every cell, row-major (index(x, y)), 1 = occupied.
  const std::vector<std::uint8_t>& occupancy() const { return occupancy_; }
  /// Indices of the cells step() changes.
  std::vector<std::size_t> dynamicCells() const;

 private:
  void check(std::int32_t x, std::int32_t y) const;

  std::int32_t width_;
  std::int32_t height_;
  double resolution_m_;
  std::vector<std::uint8_t> occupancy_;
  std::vector<std::uint8_t> random_;
  std::vector<core::TransitionParams> truth_;
};

/// Where a ray meets the first occupied cell: the distances (m) along it at which it enters
/// and leaves that cell; both +inf if there is none within max_range_m. Entry 0 when the
/// start cell itself is occupied. A ray whose chord through an occupied cell is shorter than
/// a tenth of a cell only grazes its corner and passes (objects have slightly rounded
/// corners). Exact up to rounding (the ray is intersected with the cell
/// squares).
struct RayHit {
  double entry_m;
  double exit_m;
};
RayHit castRay(const World& world, double x_m, double y_m, double angle_rad, double max_range_m);

/// A 2D laser (sensor_msgs/LaserScan conventions).
struct LaserConfig {
  int beams = 360;
  double angle_min_rad = -3.14159265358979323846;
  double angle_increment_rad = 2.0 * 3.14159265358979323846 / 360.0;
  double range_min_m = 0.05;
  double range_max_m = 8.0;
  double noise_sigma_m = 0.01;        ///< Gaussian range noise
  double dropout_probability = 0.01;  ///< a beam gives no reading (NaN)
  /// Indices of the beams that read, strictly increasing; empty: all of them. The others
  /// always read NaN (no reading, which the mapper ignores). A Scan's beams are evenly spaced,
  /// so a sensor with a few beams at uneven angles is the evenly spaced fan through them with
  /// the gaps dark: Li, Barão & Rato's four beams at -pi/2, -pi/4, pi/4, pi/2 are beams
  /// {0, 1, 3, 4} of a fan of 5 from -pi/2 in steps of pi/4.
  std::vector<int> active_beams;

  /// Throws std::invalid_argument naming the first bad field.
  void validate() const;
};

/// One scan of `laser` at `laser_pose` (every beam, dark ones NaN). A beam's true range is the middle of its chord
/// through the first occupied cell: objects of a grid world fill their cells, and reading
/// their boundary would put half of the noisy end points in the free cell in front (an
/// artefact of the grid world, not of a real laser, whose surfaces lie inside cells). Plus
/// Gaussian noise; a return at or beyond range_max (or none) reads +inf (no return), a
/// dropout NaN, a reading below range_min is clamped to range_min.
core::Scan simulateScan(const World& world, const core::Pose2D& laser_pose, const LaserConfig& laser, double stamp_s,
                  Rng& rng);

/// Odometry that drifts: each true motion between two poses, taken as rotation,
/// translation, rotation, is read with noise (the motion model's sampler, §5.4) and added
/// to the odometry pose, which starts at the first true pose. The error so grows with the
/// distance driven and is never corrected, as a wheel encoder's.
class DriftingOdometry {
 public:
  /// Throws std::invalid_argument for bad noise (OdometryNoise::validate).
  DriftingOdometry(const core::OdometryNoise& noise, std::uint64_t seed);
  /// The odometry pose once the robot has moved to `truth` (the first call: `truth`).
  core::Pose2D update(const core::Pose2D& truth);

 private:
  core::OdometryNoise noise_;
  Rng rng_;
  std::optional<core::Pose2D> last_truth_;
  core::Pose2D odometry_;
};

/// A robot driving a closed polygon at constant speed, heading along the current segment.
class LoopPath {
 public:
  /// At least two distinct waypoints (m); speed > 0 (m per step). Throws
  /// std::invalid_argument otherwise.
  LoopPath(std::vector<std::array<double, 2>> waypoints_m, double speed_m_per_step);
  /// Pose after `steps` (fractional) steps from the first waypoint.
  core::Pose2D poseAt(double steps) const;
  double lengthM() const { return cumulative_.back(); }

 private:
  std::vector<std::array<double, 2>> waypoints_;
  std::vector<double> cumulative_;  ///< distance at each waypoint; back() = loop length
  double speed_;
};

enum class ScenarioKind {
  kRandomDynamic,  ///< the papers' grid: a fraction of cells change at random
  kParkingLot,     ///< bays whose cars change every "hour"
  kDoor,           ///< a door on the short path between A and B, and a long detour
  kMrfSquares,     ///< Li, Barão & Rato's simulation: walls, four squares with fixed hold times
  kDividers,       ///< Morris et al.'s office: passages blocked by slow dividers, fast people
  kPatrol,         ///< a robot patrolling a loop: each place seen seconds every two minutes
};

/// kPatrol's floor plan (PatrolLayout).
enum class PatrolFloor {
  kTwoRooms,  ///< "patrol": slow carts that change about once in five loops
  kOffice,    ///< "patrol_office": every moving part changes within about one loop
  kSparseOffice,  ///< "sparse_office": few moving parts, each in a niche seen a few steps per loop
};

/// A named configuration of a simulated world (scenarioConfig(name)).
struct ScenarioConfig {
  std::string name;
  std::string description;
  ScenarioKind kind = ScenarioKind::kRandomDynamic;
  std::int32_t width_cells = 50;
  std::int32_t height_cells = 50;
  double resolution_m = 0.1;
  double time_step_s = 1.0;
  std::int64_t steps = 1000;  ///< length of a run
  int scans_per_step = 1;
  LaserConfig laser;
  core::Pose2D laser_mount{0.05, 0.0, 0.0};  ///< laser pose in the robot frame (base_link -> laser)
  double robot_speed_m_per_step = 0.2;
  /// The robot drives near its scripted path, not on it: every step its pose is offset by
  /// Gaussian noise of these standard deviations (each axis; heading), drawn from the run
  /// seed. 0 drives the path exactly.
  double path_noise_sigma_m = 0.0;
  double path_noise_sigma_rad = 0.0;
  /// The sensor model for mapping this scenario's scans: the laser's per-beam hit rates on
  /// occupied and free cells as measured on its runs (test_simulator checks them), rounded
  /// towards less certainty.
  double p_hit_given_occ = 0.9;
  double p_hit_given_free = 0.05;

  // kRandomDynamic
  double dynamic_fraction = 0.05;     ///< of the cells that may be dynamic (not walls, not the robot's lane)
  double change_probability = 0.05;   ///< p_occ_given_free = p_free_given_occ of every dynamic cell
  std::int64_t redraw_at_step = -1;   ///< from this step (in [1, steps)) on, a new set of dynamic cells (-1: never)

  // kParkingLot
  int hours = 12;                     ///< configurations, one run each
  std::int64_t steps_per_hour = 100;
  double p_arrive_per_hour = 0.3;     ///< an empty bay gets a car at the hour's change
  double p_leave_per_hour = 0.3;      ///< a car leaves its bay at the hour's change

  // kDoor
  double door_change_probability = 0.001;  ///< p_occ_given_free = p_free_given_occ of the door

  // kMrfSquares
  /// Steps each of the four squares holds its state before it toggles (the same for
  /// occupied and free); must be positive for this kind.
  std::array<std::int64_t, 4> square_hold_steps{};

  // kDividers (see DividersLayout for the geometry and the rules)
  /// Steps between the dividers' moves; the memory experiment's episodes are this long, so
  /// the dividers move between episodes, never while the robot drives.
  std::int64_t divider_period_steps = 150;
  /// At every move each divider toggles (open <-> closed) with this probability.
  double divider_toggle_probability = 0.2;
  int people = 3;  ///< people walking at one cell per step

  // kPatrol (see PatrolLayout): the floor and the true per-step rates of its three kinds of
  // moving parts.
  PatrolFloor patrol_floor = PatrolFloor::kTwoRooms;
  core::TransitionParams patrol_door{0.025, 0.05};      ///< doors in the rooms' walls
  core::TransitionParams patrol_cart{0.004, 0.012};     ///< carts parked in bays along the outer walls
  core::TransitionParams patrol_person{0.12, 0.25};     ///< spots where people stand and leave

  /// Throws std::invalid_argument naming the first bad field.
  void validate() const;
};

/// Names of the built-in scenarios, in the evaluation's order.
std::vector<std::string> scenarioNames();
/// The built-in scenario `name`; throws std::invalid_argument listing the names otherwise.
ScenarioConfig scenarioConfig(const std::string& name);

/// The door scenario's places (cells).
struct DoorLayout {
  core::CellXY a;            ///< one end of both paths
  core::CellXY b;            ///< the other end
  core::CellXY door;         ///< on the short path
  std::int32_t short_path_cells = 0;  ///< moves from a to b through the door
  std::int32_t long_path_cells = 0;   ///< moves from a to b along the detour
};

/// The MRF scenario's places (scenarioConfig("mrf_squares"); Li, Barão & Rato, Sec. IV).
struct MrfSquaresLayout {
  /// The lowest (x, y) cell of each square, in the order of square_hold_steps.
  std::array<core::CellXY, 4> square_corner{};
  std::int32_t square_side_cells = 0;
  /// The steps of one loop of the robot's path.
  std::int64_t loop_steps = 0;
  /// Delta t of the paper's hold times (dt/3, 2 dt, 3 dt, 7 dt), in steps: 7/8 of the loop
  /// in scenarioConfig("mrf_squares"), so that the holds are incommensurate with the loop.
  std::int64_t delta_t_steps = 0;
};

/// The dividers scenario's places and its moving parts (scenarioConfig("dividers"); Morris
/// et al., Sec. IV: an office whose paths are blocked by office dividers that move much more
/// slowly than the people walking around).
///
/// Geometry: border walls and an internal wall (column wall_x, one cell thick) splitting the
/// office into a left and a right half, crossed by passages (each passage_height cells of
/// that column). A divider is a passage's cells of the wall column, closed (occupied) or
/// open (free). The robot's two places a and b face each other across the middle passage:
/// through it the way is shortest, the others are detours.
///
/// Dividers move slowly: at steps that are multiples of divider_period_steps (never at
/// step 0) each toggles with divider_toggle_probability; if that leaves every passage
/// closed, one of the ones that just closed, picked at random, stays open. At step 0 each is
/// closed with probability 1/2, under the same rule. So at least one passage is always open.
///
/// People move fast: one cell per step (4-connected) towards a waypoint (a random free
/// cell that is not in the wall column), each step picking at random among the moves that
/// shorten the Manhattan distance to it and lead into a cell free of structure and of the
/// other people; when there is none (arrived, or stuck at the wall), a new waypoint is drawn
/// and the person takes a random free step (it stands still only when boxed in). People
/// walk through open passages; a divider closing on a person pushes that person to the
/// nearest free cell. People do not know about the robot: the world's dynamics must not
/// depend on what a robot does (the memory experiment drives three robots through the same
/// world timeline); the robot must not step into a person (a move into an occupied cell
/// fails), and a person passing through the robot's cell is not seen by its laser (too
/// close). All moves draw from the run seed's dynamics stream.
///
/// Ground truth: World::occupied = structure (walls, closed dividers) or a person; the
/// Simulation tells them apart at every step (isStructure, isPerson).
struct DividersLayout {
  std::int32_t wall_x = 0;
  std::int32_t passage_height = 0;
  std::vector<std::int32_t> passage_min_y;  ///< the lowest cell row of each passage, ascending
  core::CellXY a;  ///< left half
  core::CellXY b;  ///< right half
  std::vector<std::uint8_t> closed;  ///< now, per passage (1 = its divider is closed)
  std::vector<core::CellXY> people;        ///< now

  /// Whether (x, y) is a cell of passage p's divider (open or closed).
  bool inDivider(std::size_t p, std::int32_t x, std::int32_t y) const {
    return x == wall_x && y >= passage_min_y[p] && y < passage_min_y[p] + passage_height;
  }
  /// The passage whose divider holds (x, y), or -1.
  int dividerAt(std::int32_t x, std::int32_t y) const;
};

/// The patrol scenarios' places. Each moving part is a group of cells that changes as one, a
/// two-state Markov chain with its kind's rates (ScenarioConfig::patrol_*), started from its
/// stationary distribution; the groups draw from the run seed's dynamics stream.
///
/// PatrolFloor::kTwoRooms (scenarioConfig("patrol")): a 24 m x 14 m floor, a block of two
/// rooms in the middle, a corridor around it that the robot drives as a 56 m loop (112 steps
/// at 0.5 m per step), a 360° laser of 3 m: every place is in view for about ten steps per
/// loop. Doors (1 m gaps in the rooms' walls, through which the robot sees the rooms), carts
/// (0.6 m x 1.2 m in bays along the outer walls), people (0.3 m spots beside the corridor).
///
/// PatrolFloor::kOffice (scenarioConfig("patrol_office")): a 20 m x 14 m office, a block of
/// three rooms in the middle with five doors (1 m leaves one cell thick), a 50 m loop around
/// it (100 steps), a 360° laser of 4 m; three 0.6 m x 0.6 m carts parked against the outer
/// walls and eight 0.3 m spots where people stand. Doors, carts and people all forget their state within about
/// one loop, so what the map should show of a place the robot left is its long-run state.
///
/// PatrolFloor::kSparseOffice (scenarioConfig("sparse_office")): a 16 m x 12 m office at
/// 0.05 m, corridors 1.6 m wide that the robot drives as a 60 m loop with a notch (120 steps),
/// a 360° laser of 5.6 m. Few places change (0.4 % of the cells), each set back from the
/// corridor so that the laser sees it for 6 to 10 steps of a loop: three doors (1 m leaves at
/// the back of 0.8 m recesses, a room behind each), four parking bays (0.6 m x 0.4 m carts
/// in 0.9 m deep niches), six busy 0.3 m spots (in 1.2 m deep alcoves). Here a part's cells
/// are the outline of its rectangle, one cell thick: its inside, which the laser never sees
/// while the part is there, is floor.
struct PatrolLayout {
  struct Part {
    std::string kind;           ///< "door", "cart" or "person"
    std::vector<core::CellXY> cells;
    core::TransitionParams truth;
  };
  std::vector<Part> parts;
};

/// A run of a scenario: the world with its scheduled events, the scripted robot, the laser.
class Simulation {
 public:
  /// `world_seed` draws the layout (which cells are dynamic, the walls of the parking lot),
  /// `run_seed` everything that happens (state changes, parked cars, sensor noise): runs
  /// with the same world seed and different run seeds are the same place on different days
  /// (an offline training run and an evaluation run). Throws std::invalid_argument for a
  /// bad configuration.
  Simulation(const ScenarioConfig& config, std::uint64_t world_seed, std::uint64_t run_seed);

  const ScenarioConfig& config() const { return config_; }
  const World& world() const { return world_; }
  /// The current step (0 at the start).
  std::int64_t step() const { return step_; }

  /// The robot's pose at scan `scan_index` of the current step: the scripted path's, plus
  /// the step's path noise (ScenarioConfig::path_noise_sigma_m).
  core::Pose2D robotPose(int scan_index = 0) const;
  /// Scan `scan_index` (0 .. scans_per_step - 1) of the current step from the scripted
  /// robot; stamped (step + (scan_index + 0.5) / scans_per_step) * time_step_s.
  core::Scan scan(int scan_index = 0);
  /// The same from any robot pose (a robot driven by a planner).
  core::Scan scanFrom(const core::Pose2D& robot_pose, int scan_index = 0);
  /// Ends the current step: the random changes of the dynamic cells, then the events
  /// scheduled for the next step (re-drawing the dynamic cells, the parking lot's hour, the
  /// squares' toggles) and the next step's path noise.
  void advance();

  /// The door scenario's places; throws std::logic_error for another scenario.
  const DoorLayout& doorLayout() const;
  /// The MRF scenario's places; throws std::logic_error for another scenario.
  const MrfSquaresLayout& mrfSquaresLayout() const;
  /// The dividers scenario's places, dividers and people now; throws std::logic_error for
  /// another scenario.
  const DividersLayout& dividersLayout() const;
  /// The patrol scenario's places; throws std::logic_error for another scenario.
  const PatrolLayout& patrolLayout() const;
  /// Dividers scenario: (x, y) is occupied now by a wall or a closed divider / by a person
  /// (never both). Other scenarios: isStructure = World::occupied, isPerson = false.
  bool isStructure(std::int32_t x, std::int32_t y) const;
  bool isPerson(std::int32_t x, std::int32_t y) const;

 private:
  void buildRandomDynamic();
  void drawDynamicCells(Rng& layout_rng);
  void buildParkingLot();
  void parkingHour();
  void buildDoor();
  void buildMrfSquares();
  void toggleSquares();
  void drawPathNoise();
  void addBorderWalls();
  void buildDividers();
  void buildPatrol();
  void startPatrolParts();
  void stepPatrolParts();
  void moveDividers(bool initial);
  void movePeople();
  bool freeForPerson(std::int32_t x, std::int32_t y) const;
  core::CellXY randomFreeCell(Rng& rng) const;

  ScenarioConfig config_;
  World world_;
  Rng layout_rng_;
  Rng dynamics_rng_;
  Rng sensor_rng_;
  Rng path_rng_;
  std::int64_t step_ = 0;
  core::Pose2D path_noise_;                                  ///< this step's offset from the path
  std::vector<std::array<double, 2>> route_;           ///< the scripted robot's loop
  std::optional<LoopPath> path_;
  std::vector<std::size_t> free_candidates_;           ///< cells that may become dynamic
  std::vector<std::vector<std::size_t>> bays_;         ///< parking: the cells of each car
  std::vector<std::uint8_t> bay_occupied_;
  DoorLayout door_;
  MrfSquaresLayout squares_;
  std::array<std::int64_t, 4> square_next_toggle_{};  ///< the step at which each square toggles next
  DividersLayout dividers_;
  PatrolLayout patrol_;
  std::vector<std::uint8_t> part_occupied_;            ///< patrol: per part, now
  std::vector<core::CellXY> waypoints_;                      ///< dividers: each person's waypoint
};

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
