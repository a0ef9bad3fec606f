#include "dynamic_occupancy_grid/evaluation/path_planning.h"

#include "dynamic_occupancy_grid/core/common/parallel.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <memory>
#include <stdexcept>

#include "dynamic_occupancy_grid/evaluation/evaluation.h"
#include "dynamic_occupancy_grid/evaluation/planner.h"

namespace dynamic_occupancy_grid {
namespace evaluation {
namespace {

void require(bool ok, const std::string& message) {
  if (!ok) throw std::invalid_argument(message);
}

std::size_t policyIndex(const std::vector<Policy>& policies, Policy policy) {
  const auto it = std::find(policies.begin(), policies.end(), policy);
  if (it == policies.end()) throw std::invalid_argument("path planning: policy " + policyName(policy) + " was not run");
  return static_cast<std::size_t>(it - policies.begin());
}

// The map a policy plans on, and the method whose belief of the door random and optimal
// hold (the oracle: the true transitions, filtered on the robot's own scans).
Method planningMethod(Policy policy) {
  switch (policy) {
    case Policy::kStatic:
      return Method::kStaticUnclamped;
    case Policy::kOnline:
      return Method::kOnline;
    case Policy::kOffline:
      return Method::kOffline;
    case Policy::kRandom:
    case Policy::kOptimal:
      return Method::kOracle;
  }
  throw std::invalid_argument("path planning: unknown policy");
}

// Offline EM's iteration cap here (the tools use 100). Measured on this scenario after
// 20064 exploration steps: the door's learned transitions agree to 5 digits with 30 and with
// 100 iterations; the cells that run into the cap are static walls whose probabilities creep
// towards p_min; and 100 iterations take 1.9 s per repetition against 0.5 s, more than
// the whole rest of a repetition.
constexpr int kOfflineEmIterations = 30;

bool committingPolicy(Policy policy) { return policy == Policy::kRandom || policy == Policy::kOptimal; }

// Cells along the short path from which a closed door is surely seen: the laser at a cell
// centre n cells before the door reads the middle of the door cell's chord (simulateScan),
// n cells away, a return only while that is below range_max. Exactly at range_max (n = 6
// here) only readings with negative noise return, about half of them: the door may be seen
// a cell earlier.
std::int32_t doorVisibleCells(const ScenarioConfig& door) {
  return static_cast<std::int32_t>(std::ceil(door.laser.range_max_m / door.resolution_m)) - 1;
}

// One policy's robot: its own simulation (a copy of the explored one), maps and planner.
struct Robot {
  Robot(Policy policy_in, const core::MapperConfig& mapper_config, const World& world, std::uint64_t coin_seed)
      : policy(policy_in), mappers(mapper_config, world), coin(coin_seed), blocked(world.width(), world.height()) {}

  Policy policy;
  MethodMappers mappers;
  Rng coin;  // the random policy's choices: the same whichever other policies run
  std::optional<Simulation> simulation;  // set when exploration is over
  AStarPlanner planner;
  BlockedGrid blocked;
  core::CellXY cell;
  double yaw_rad = 0.0;
  std::vector<std::uint8_t> door_open;  // by step, from step 0
  std::vector<RunRecord> runs;
};

class RepetitionRunner {
 public:
  RepetitionRunner(const ScenarioConfig& door, const PathPlanningConfig& config, int repetition)
      : scenario_(door), config_(config), repetition_(repetition), mapper_config_(evaluationMapperConfig(door)) {}

  // Fills runs[p] (in config.policies order) and the exploration summary.
  void run(std::vector<std::vector<RunRecord>>* runs, ExplorationSummary* summary) {
    const std::uint64_t world_seed = mixSeed(config_.seed * 1000003ULL + static_cast<std::uint64_t>(repetition_));
    const std::uint64_t run_seed = mixSeed(world_seed ^ 0x646f6f72ULL);
    Simulation exploration(scenario_, world_seed, run_seed);
    layout_ = exploration.doorLayout();
    // Same seeds, nothing drawn yet: trainOffline will see exactly the exploration's scans.
    Simulation training = exploration;

    std::vector<std::unique_ptr<Robot>> robots;
    for (const Policy policy : config_.policies) {
      robots.push_back(
          std::make_unique<Robot>(policy, mapper_config_, exploration.world(), mixSeed(run_seed ^ 0x72616e64ULL)));
      // The oracle knows the true transitions from the start: with the prior's instead, its
      // a-priori map would forget the static walls it saw long ago.
      robots.back()->mappers.setOracle(exploration.world());
    }
    std::vector<std::uint8_t> door_open;
    recordDoor(exploration, &door_open);
    for (std::int64_t t = 0; t < config_.exploration_steps; ++t) {
      for (int k = 0; k < scenario_.scans_per_step; ++k) {
        const core::Scan scan = exploration.scan(k);
        for (auto& robot : robots) robot->mappers.integrate(scan);
      }
      for (auto& robot : robots) robot->mappers.finishStep();
      exploration.advance();
      recordDoor(exploration, &door_open);
    }
    core::OfflineEmConfig em_config = evaluationOfflineEmConfig(mapper_config_);
    em_config.max_iterations = kOfflineEmIterations;
    const OfflineTraining offline = trainOffline(training, mapper_config_, config_.exploration_steps, em_config);

    summary->door_changes = 0;
    std::int64_t open_steps = 0;
    for (std::int64_t t = 0; t < config_.exploration_steps; ++t) {
      open_steps += door_open[t];
      if (door_open[t + 1] != door_open[t]) ++summary->door_changes;
    }
    summary->door_open_fraction = static_cast<double>(open_steps) / static_cast<double>(config_.exploration_steps);
    for (auto& robot : robots) {
      robot->mappers.setOffline(offline);
      robot->simulation.emplace(exploration);
      robot->door_open = door_open;
      robot->cell = layout_.a;
    }
    // All robots' maps are the same after exploration; a door never seen keeps the prior.
    const Robot& any = *robots.front();
    summary->offline_door = any.mappers.transitions(Method::kOffline, layout_.door.x, layout_.door.y)
                                .value_or(mapper_config_.prior_transitions);
    summary->online_door = any.mappers.transitions(Method::kOnline, layout_.door.x, layout_.door.y)
                               .value_or(mapper_config_.prior_transitions);

    runs->clear();
    for (auto& robot : robots) {
      for (int i = 0; i < config_.runs; ++i) runOnce(*robot, i % 2 == 0);
      // No look-ahead is needed: a run that did not time out ended no earlier than the
      // steps its classification reads (a robot going straight, or the ideal detour).
      for (RunRecord& record : robot->runs) {
        record.run_class = classifyRun(record.trace, geometry(record.from_a), robot->door_open);
      }
      runs->push_back(std::move(robot->runs));
    }
  }

 private:
  void recordDoor(const Simulation& simulation, std::vector<std::uint8_t>* door_open) const {
    // One entry per step: index = step.
    if (static_cast<std::int64_t>(door_open->size()) != simulation.step()) {
      throw std::logic_error("path planning: door record out of step");
    }
    door_open->push_back(simulation.world().occupied(layout_.door.x, layout_.door.y) ? 0 : 1);
  }

  RunGeometry geometry(bool from_a) const {
    RunGeometry g;
    g.door_progress = from_a ? layout_.door.x - layout_.a.x : layout_.b.x - layout_.door.x;
    g.short_path_cells = layout_.short_path_cells;
    g.long_path_cells = layout_.long_path_cells;
    return g;
  }

  // Cells along the short path from the start, for cells of the corridor; -1 elsewhere.
  std::int32_t progress(core::CellXY cell, bool from_a) const {
    if (cell.y != layout_.a.y || cell.x < layout_.a.x || cell.x > layout_.b.x) return -1;
    return from_a ? cell.x - layout_.a.x : layout_.b.x - cell.x;
  }

  void advance(Robot& robot) const {
    robot.simulation->advance();
    recordDoor(*robot.simulation, &robot.door_open);
  }

  core::Pose2D pose(const Robot& robot) const {
    const double r = scenario_.resolution_m;
    return core::Pose2D{(robot.cell.x + 0.5) * r, (robot.cell.y + 0.5) * r, robot.yaw_rad};
  }

  // p(occ) > 0.5 of the policy's map; never-observed cells (NaN) are free.
  void fillBlocked(Robot& robot) const {
    const Method method = planningMethod(robot.policy);
    for (std::int32_t y = 0; y < robot.blocked.height(); ++y) {
      for (std::int32_t x = 0; x < robot.blocked.width(); ++x) {
        robot.blocked.setBlocked(x, y, robot.mappers.belief(method, x, y) > 0.5);
      }
    }
  }

  // The optimal policy's choice at departure: the expected time of the short path against
  // the long one, from the oracle's filtered belief of the door and its true transitions.
  bool optimalTakesShort(const Robot& robot, const RunGeometry& g) const {
    const double belief = robot.mappers.belief(Method::kOracle, layout_.door.x, layout_.door.y);
    const double p_occ_now = std::isnan(belief) ? mapper_config_.initial_p_occ : belief;
    const core::TransitionParams truth = robot.simulation->world().truth(layout_.door.x, layout_.door.y);
    // The move into the door is decided door_progress - 1 steps after departure.
    const double p_closed = core::predictOccupancy(p_occ_now, truth, g.door_progress - 1);
    const std::int32_t sighting = std::max(0, g.door_progress - doorVisibleCells(scenario_));
    const double expected_short =
        (1.0 - p_closed) * g.short_path_cells + p_closed * (2.0 * sighting + g.long_path_cells);
    return expected_short < g.long_path_cells;
  }

  // Random and optimal: the path chosen at departure (door free in their plan: the short
  // one), given up once they find the door closed.
  struct Commitment {
    bool decided = false;
    bool door_free = true;
  };

  void runOnce(Robot& robot, bool from_a) {
    Simulation& simulation = *robot.simulation;
    for (std::int64_t t = 0; t < config_.idle_steps; ++t) advance(robot);

    const core::CellXY goal = from_a ? layout_.b : layout_.a;
    robot.cell = from_a ? layout_.a : layout_.b;
    RunRecord record;
    record.from_a = from_a;
    record.trace.departure_step = simulation.step();
    Commitment commitment;
    bool finished = false;
    while (!finished) {
      for (int k = 0; k < scenario_.scans_per_step; ++k) robot.mappers.integrate(simulation.scanFrom(pose(robot), k));
      robot.mappers.finishStep();
      const std::int64_t elapsed = simulation.step() - record.trace.departure_step;
      if (robot.cell == goal) {
        record.steps = elapsed;
        finished = true;
      } else if (elapsed >= config_.max_run_steps) {
        record.trace.timed_out = true;
        record.steps = elapsed;
        robot.cell = goal;  // the next run starts where it should
        finished = true;
      } else {
        moveOnce(robot, goal, from_a, &commitment, &record.trace);
      }
      // The arrival step ends too: parking starts with the next one.
      advance(robot);
    }
    robot.runs.push_back(record);
  }

  // One step of a run after the scan: the next cell by A* on the policy's map, and the
  // move, unless that cell is occupied in truth.
  void moveOnce(Robot& robot, core::CellXY goal, bool from_a, Commitment* commitment, RunTrace* trace) const {
    const Simulation& simulation = *robot.simulation;
    fillBlocked(robot);
    if (committingPolicy(robot.policy)) {
      if (!commitment->decided) {
        commitment->door_free = robot.policy == Policy::kRandom ? robot.coin.bernoulli(0.5)
                                                                : optimalTakesShort(robot, geometry(from_a));
        commitment->decided = true;
      }
      if (commitment->door_free && doorFoundClosed(robot, trace->departure_step)) commitment->door_free = false;
      robot.blocked.setBlocked(layout_.door.x, layout_.door.y, !commitment->door_free);
    }
    const std::vector<core::CellXY> path = robot.planner.plan(robot.blocked, robot.cell, goal);
    // No path in the map: stay, the map may change (a timeout if it does not).
    const core::CellXY next = path.size() >= 2 ? path[1] : robot.cell;
    if (next == robot.cell || simulation.world().occupied(next.x, next.y)) return;
    const std::int32_t from = progress(robot.cell, from_a);
    const std::int32_t to = progress(next, from_a);
    if (from >= 0 && to >= 0 && to < from && !trace->turn) trace->turn = ShortPathTurn{from, simulation.step()};
    robot.yaw_rad = std::atan2(static_cast<double>(next.y - robot.cell.y), static_cast<double>(next.x - robot.cell.x));
    robot.cell = next;
    if (next == layout_.door) trace->passed_door = true;
  }

  // Observed during this run (last update at or after departure) and classified occupied.
  // Mapper steps are simulation steps: the first scan of all was at step 0.
  bool doorFoundClosed(const Robot& robot, std::int64_t departure_step) const {
    const std::optional<core::CellState> cell =
        robot.mappers.mapper(Method::kOracle).grid().cell(layout_.door.x, layout_.door.y);
    return cell && cell->last_step >= departure_step &&
           robot.mappers.belief(Method::kOracle, layout_.door.x, layout_.door.y) > 0.5;
  }

  const ScenarioConfig& scenario_;
  const PathPlanningConfig& config_;
  int repetition_;
  core::MapperConfig mapper_config_;
  DoorLayout layout_;
};

}  // namespace

MeanStd meanStd(const std::vector<double>& values) {
  MeanStd result;
  if (values.empty()) return result;
  double sum = 0.0;
  for (const double v : values) sum += v;
  result.mean = sum / static_cast<double>(values.size());
  if (values.size() < 2) return result;
  double squares = 0.0;
  for (const double v : values) squares += (v - result.mean) * (v - result.mean);
  result.std = std::sqrt(squares / static_cast<double>(values.size() - 1));
  return result;
}

std::string policyName(Policy policy) {
  switch (policy) {
    case Policy::kStatic:
      return "static";
    case Policy::kOnline:
      return "online";
    case Policy::kOffline:
      return "offline";
    case Policy::kRandom:
      return "random";
    case Policy::kOptimal:
      return "optimal";
  }
  return "unknown";
}

std::string runClassName(RunClass run_class) {
  switch (run_class) {
    case RunClass::kShort:
      return "short";
    case RunClass::kLong:
      return "long";
    case RunClass::kIndirectLong:
      return "indirect long";
    case RunClass::kUnnecessaryIndirectLong:
      return "unnecessary indirect long";
    case RunClass::kUnnecessaryDirectLong:
      return "unnecessary direct long";
    case RunClass::kTimeout:
      return "timeout";
  }
  return "unknown";
}

RunClass classifyRun(const RunTrace& trace, const RunGeometry& geometry, const std::vector<std::uint8_t>& door_open) {
  if (trace.timed_out) return RunClass::kTimeout;
  if (trace.passed_door) return RunClass::kShort;
  const auto open_at = [&door_open](std::int64_t step) {
    if (step < 0 || step >= static_cast<std::int64_t>(door_open.size())) {
      throw std::out_of_range("classifyRun: the door record does not reach step " + std::to_string(step));
    }
    return door_open[static_cast<std::size_t>(step)] != 0;
  };
  // The alternative to the long path, judged the same way for direct and indirect runs:
  // walk to the door from where the robot was, enter at the first open step (waiting if
  // needed); it was better iff it arrives strictly before the long path does.
  const std::int64_t after_door = geometry.short_path_cells - geometry.door_progress;
  const auto waiting_wins = [&](std::int64_t at_door_from, std::int64_t long_arrival) {
    // Entering at step s arrives at s + 1 + after_door.
    for (std::int64_t s = at_door_from; s + 1 + after_door < long_arrival; ++s) {
      if (open_at(s)) return true;
    }
    return false;
  };
  if (!trace.turn) {
    return waiting_wins(trace.departure_step + geometry.door_progress - 1,
                        trace.departure_step + geometry.long_path_cells)
               ? RunClass::kUnnecessaryDirectLong
               : RunClass::kLong;
  }
  const ShortPathTurn& turn = *trace.turn;
  return waiting_wins(turn.step + geometry.door_progress - 1 - turn.progress,
                      turn.step + turn.progress + geometry.long_path_cells)
             ? RunClass::kUnnecessaryIndirectLong
             : RunClass::kIndirectLong;
}

void PathPlanningConfig::validate() const {
  require(repetitions > 0, "path planning: repetitions must be positive");
  require(runs > 0, "path planning: runs must be positive");
  require(exploration_steps > 0, "path planning: exploration_steps must be positive");
  require(idle_steps >= 0, "path planning: idle_steps must not be negative");
  require(max_run_steps > 0, "path planning: max_run_steps must be positive");
  require(!policies.empty(), "path planning: policies must not be empty");
  for (std::size_t i = 0; i < policies.size(); ++i) {
    require(std::find(policies.begin() + static_cast<std::ptrdiff_t>(i) + 1, policies.end(), policies[i]) ==
                policies.end(),
            "path planning: policy " + policyName(policies[i]) + " is listed twice");
  }
}

MeanStd PathPlanningResult::classPercent(Policy policy, RunClass run_class) const {
  std::vector<double> percent;
  for (const std::vector<RunRecord>& repetition : runs[policyIndex(policies, policy)]) {
    const auto count = std::count_if(repetition.begin(), repetition.end(),
                                     [run_class](const RunRecord& r) { return r.run_class == run_class; });
    percent.push_back(100.0 * static_cast<double>(count) / static_cast<double>(repetition.size()));
  }
  return meanStd(percent);
}

MeanStd PathPlanningResult::effectiveness(Policy policy) const {
  std::vector<double> percent;
  for (const std::vector<RunRecord>& repetition : runs[policyIndex(policies, policy)]) {
    const auto count = std::count_if(repetition.begin(), repetition.end(), [](const RunRecord& r) {
      return r.run_class == RunClass::kShort || r.run_class == RunClass::kLong;
    });
    percent.push_back(100.0 * static_cast<double>(count) / static_cast<double>(repetition.size()));
  }
  return meanStd(percent);
}

PathPlanningResult runPathPlanningExperiment(const ScenarioConfig& door, const PathPlanningConfig& config,
                                             const std::function<void(int done)>& progress) {
  door.validate();
  require(door.kind == ScenarioKind::kDoor, "path planning: scenario " + door.name + " is not a door scenario");
  config.validate();
  const auto start = std::chrono::steady_clock::now();
  const auto repetitions = static_cast<std::size_t>(config.repetitions);
  std::vector<std::vector<std::vector<RunRecord>>> by_repetition(repetitions);
  std::vector<ExplorationSummary> exploration(repetitions);
  core::runRepetitions(
      repetitions, config.threads,
      [&](std::size_t r) {
        RepetitionRunner(door, config, static_cast<int>(r)).run(&by_repetition[r], &exploration[r]);
      },
      progress);

  PathPlanningResult result;
  result.policies = config.policies;
  result.runs.resize(config.policies.size());
  for (std::size_t p = 0; p < config.policies.size(); ++p) {
    for (std::vector<std::vector<RunRecord>>& repetition : by_repetition) {
      result.runs[p].push_back(std::move(repetition[p]));
    }
  }
  result.exploration = std::move(exploration);
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

std::optional<MeanStd> paperTable1(Policy policy, RunClass run_class) {
  // Rows in kAllRunClasses order (timeouts excluded), columns static, online, offline,
  // random, optimal; kIllegible marks the entry our copy of the text does not show.
  constexpr double kIllegible = -1.0;
  constexpr MeanStd kTable[5][5] = {
      {{11.25, 16.35}, {25.50, 22.24}, {40.75, 20.15}, {24.25, 10.17}, {40.50, 19.99}},
      {{35.75, 14.80}, {27.00, 18.38}, {15.00, 9.03}, {24.25, 13.70}, {17.25, 9.39}},
      {{4.75, 1.12}, {19.50, 12.24}, {30.50, 8.72}, {23.50, 9.33}, {27.75, 9.24}},
      {{kIllegible, kIllegible}, {1.50, 2.86}, {2.75, 3.02}, {1.50, 2.86}, {2.25, 3.02}},
      {{48.00, 16.89}, {26.50, 21.34}, {11.00, 5.28}, {26.50, 13.19}, {12.25, 6.38}},
  };
  if (run_class == RunClass::kTimeout) return std::nullopt;
  const MeanStd value = kTable[static_cast<int>(run_class)][static_cast<int>(policy)];
  if (value.mean == kIllegible) return std::nullopt;
  return value;
}

MeanStd paperEffectiveness(Policy policy) {
  constexpr MeanStd kEffectiveness[5] = {{47.00, 16.89}, {52.50, 16.10}, {55.75, 13.21}, {48.50, 10.14}, {57.75, 14.09}};
  return kEffectiveness[static_cast<int>(policy)];
}

std::string formatPathPlanningTable(const PathPlanningResult& result) {
  const auto cell = [](const MeanStd& ours, const std::optional<MeanStd>& paper) {
    char text[96];
    if (paper) {
      std::snprintf(text, sizeof(text), "%6.2f ± %5.2f (%5.2f ± %5.2f)", ours.mean, ours.std, paper->mean, paper->std);
    } else {
      std::snprintf(text, sizeof(text), "%6.2f ± %5.2f (      -      )", ours.mean, ours.std);
    }
    return std::string(text);
  };
  const auto padded = [](std::string text, std::size_t width) {
    text.resize(std::max(text.size(), width), ' ');
    return text;
  };
  std::string out = padded("% of runs: ours (paper)", 27);
  for (const Policy policy : result.policies) out += " | " + padded(policyName(policy), 30);
  out += "\n";
  for (const RunClass run_class : kAllRunClasses) {
    out += padded(runClassName(run_class), 27);
    for (const Policy policy : result.policies) {
      out += " | " + cell(result.classPercent(policy, run_class), paperTable1(policy, run_class));
    }
    out += "\n";
  }
  out += padded("effectiveness", 27);
  for (const Policy policy : result.policies) {
    out += " | " + cell(result.effectiveness(policy), paperEffectiveness(policy));
  }
  out += "\n";
  return out;
}

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
