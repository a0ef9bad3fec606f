// Tests of the path planning experiment (evaluation/path_planning.h): the hindsight classification
// on hand-made door trajectories, the policies' behaviour where the right answer is known
// (a door that never changes), the random policy's coin, the paper's table, and the
// reproducibility the experiment promises (seeds, thread count, the other policies run).

#include "dynamic_occupancy_grid/evaluation/path_planning.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

namespace evaluation = dynamic_occupancy_grid::evaluation;

namespace {

// The door scenario from A: the door 13 cells along the 27-cell short path, a 51-cell detour.
evaluation::RunGeometry fromA() {
  evaluation::RunGeometry g;
  g.door_progress = 13;
  g.short_path_cells = 27;
  g.long_path_cells = 51;
  return g;
}

std::vector<std::uint8_t> doorOpenBetween(std::size_t steps, std::int64_t first_open, std::int64_t last_open) {
  std::vector<std::uint8_t> open(steps, 0);
  for (std::int64_t t = first_open; t <= last_open; ++t) open[static_cast<std::size_t>(t)] = 1;
  return open;
}

evaluation::RunTrace turnedAt(std::int64_t departure, std::int32_t progress, std::int64_t step) {
  evaluation::RunTrace trace;
  trace.departure_step = departure;
  trace.turn = evaluation::ShortPathTurn{progress, step};
  return trace;
}

// A small, fast experiment on a door that never changes (p = 0): whether it is open or
// closed throughout depends on the repetition (the door's initial state is a coin flip).
evaluation::PathPlanningConfig smallConfig() {
  evaluation::PathPlanningConfig config;
  config.repetitions = 6;
  config.runs = 10;
  config.exploration_steps = 4 * 152;  // four exploration loops: the door seen from both sides
  config.idle_steps = 20;
  config.max_run_steps = 300;
  config.seed = 3;
  config.threads = 2;
  return config;
}

evaluation::ScenarioConfig frozenDoor() {
  evaluation::ScenarioConfig door = evaluation::scenarioConfig("door");
  door.door_change_probability = 0.0;
  return door;
}

std::size_t indexOf(const evaluation::PathPlanningResult& result, evaluation::Policy policy) {
  for (std::size_t p = 0; p < result.policies.size(); ++p) {
    if (result.policies[p] == policy) return p;
  }
  ADD_FAILURE() << "policy " << evaluation::policyName(policy) << " not in the result";
  return 0;
}

bool sameRuns(const std::vector<evaluation::RunRecord>& a, const std::vector<evaluation::RunRecord>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    const evaluation::RunTrace& ta = a[i].trace;
    const evaluation::RunTrace& tb = b[i].trace;
    const bool same_turn = ta.turn.has_value() == tb.turn.has_value() &&
                           (!ta.turn || (ta.turn->progress == tb.turn->progress && ta.turn->step == tb.turn->step));
    if (a[i].from_a != b[i].from_a || a[i].steps != b[i].steps || a[i].run_class != b[i].run_class ||
        ta.departure_step != tb.departure_step || ta.passed_door != tb.passed_door || ta.timed_out != tb.timed_out ||
        !same_turn) {
      return false;
    }
  }
  return true;
}

}  // namespace

// ---- classification on hand-made door trajectories ------------------------------------

TEST(ClassifyRun, TimeoutAndShortWhateverTheDoor) {
  const std::vector<std::uint8_t> closed(400, 0);
  evaluation::RunTrace trace;
  trace.departure_step = 100;
  trace.timed_out = true;
  EXPECT_EQ(evaluation::classifyRun(trace, fromA(), closed), evaluation::RunClass::kTimeout);
  trace.timed_out = false;
  trace.passed_door = true;
  EXPECT_EQ(evaluation::classifyRun(trace, fromA(), closed), evaluation::RunClass::kShort);
  // A run that went through the door after turning back once is still short.
  trace.turn = evaluation::ShortPathTurn{7, 107};
  EXPECT_EQ(evaluation::classifyRun(trace, fromA(), closed), evaluation::RunClass::kShort);
}

TEST(ClassifyRun, DirectLongAgainstWaitingAtTheDoor) {
  // Departure at 100, door 13 cells on: a robot going straight is at the door from step 112
  // and arrives at s + 1 + 14 if it enters at s; the long path arrives at 151. Waiting wins
  // iff the door opens at some s in [112, 135].
  evaluation::RunTrace trace;
  trace.departure_step = 100;
  EXPECT_EQ(evaluation::classifyRun(trace, fromA(), doorOpenBetween(200, 112, 199)),
            evaluation::RunClass::kUnnecessaryDirectLong);
  EXPECT_EQ(evaluation::classifyRun(trace, fromA(), doorOpenBetween(200, 135, 199)),
            evaluation::RunClass::kUnnecessaryDirectLong);
  // Opening at 136 only ties with the long path: not faster.
  EXPECT_EQ(evaluation::classifyRun(trace, fromA(), doorOpenBetween(200, 136, 199)), evaluation::RunClass::kLong);
  // Open only before the robot could get there: the long path was right.
  EXPECT_EQ(evaluation::classifyRun(trace, fromA(), doorOpenBetween(200, 0, 111)), evaluation::RunClass::kLong);
  EXPECT_THROW(evaluation::classifyRun(trace, fromA(), std::vector<std::uint8_t>(130, 0)), std::out_of_range);
}

TEST(ClassifyRun, IndirectLongAgainstWaitingAtTheDoor) {
  // Turned back 7 cells along at step 107 (departure 100). The detour arrives at
  // 107 + 7 + 51 = 165. Waiting: at the cell before the door at 107 + 5 = 112, enter at the
  // first open step s >= 112, arrive at s + 1 + 14: faster iff s + 15 < 165, i.e. s <= 149.
  const evaluation::RunTrace trace = turnedAt(100, 7, 107);
  EXPECT_EQ(evaluation::classifyRun(trace, fromA(), doorOpenBetween(300, 149, 299)),
            evaluation::RunClass::kUnnecessaryIndirectLong);
  // Opening at 150 only ties with the detour: not faster.
  EXPECT_EQ(evaluation::classifyRun(trace, fromA(), doorOpenBetween(300, 150, 299)),
            evaluation::RunClass::kIndirectLong);
  // Open only before the robot could have got there (up to step 111): no help either.
  EXPECT_EQ(evaluation::classifyRun(trace, fromA(), doorOpenBetween(300, 0, 111)), evaluation::RunClass::kIndirectLong);
  // Open just when it would have got there.
  EXPECT_EQ(evaluation::classifyRun(trace, fromA(), doorOpenBetween(300, 112, 112)),
            evaluation::RunClass::kUnnecessaryIndirectLong);
  // Turned back standing in front of the door (progress 12) at step 140, after waiting:
  // waiting on from there beats a detour arriving at 140 + 12 + 51 = 203 iff it opens by 187.
  const evaluation::RunTrace waited = turnedAt(100, 12, 140);
  EXPECT_EQ(evaluation::classifyRun(waited, fromA(), doorOpenBetween(300, 187, 299)),
            evaluation::RunClass::kUnnecessaryIndirectLong);
  EXPECT_EQ(evaluation::classifyRun(waited, fromA(), doorOpenBetween(300, 188, 299)),
            evaluation::RunClass::kIndirectLong);
}

TEST(ClassifyRun, RefusesADoorRecordTooShortForTheDecision) {
  evaluation::RunTrace direct;
  direct.departure_step = 100;
  EXPECT_THROW(evaluation::classifyRun(direct, fromA(), std::vector<std::uint8_t>(112, 0)), std::out_of_range);
  EXPECT_THROW(evaluation::classifyRun(turnedAt(100, 7, 107), fromA(), std::vector<std::uint8_t>(140, 0)),
               std::out_of_range);
}

// ---- the policies on a door that never changes ------------------------------------------

TEST(PathPlanningExperiment, PoliciesOnADoorThatNeverChanges) {
  const evaluation::ScenarioConfig door = frozenDoor();
  const evaluation::PathPlanningConfig config = smallConfig();
  const evaluation::PathPlanningResult result = evaluation::runPathPlanningExperiment(door, config);
  ASSERT_EQ(result.exploration.size(), 6U);
  const evaluation::Simulation simulation(door, 1, 1);
  const evaluation::DoorLayout& layout = simulation.doorLayout();

  int open_repetitions = 0;
  int closed_repetitions = 0;
  int random_tried_short = 0;
  int random_runs = 0;
  for (std::size_t r = 0; r < result.exploration.size(); ++r) {
    const double open_fraction = result.exploration[r].door_open_fraction;
    ASSERT_TRUE(open_fraction == 0.0 || open_fraction == 1.0);
    const bool open = open_fraction == 1.0;
    (open ? open_repetitions : closed_repetitions) += 1;
    EXPECT_EQ(result.exploration[r].door_changes, 0);
    for (const evaluation::Policy policy : evaluation::kAllPolicies) {
      for (const evaluation::RunRecord& run : result.runs[indexOf(result, policy)][r]) {
        SCOPED_TRACE(::testing::Message() << evaluation::policyName(policy) << " repetition " << r
                                          << (open ? " (open)" : " (closed)"));
        EXPECT_FALSE(run.trace.timed_out);
        const std::int32_t door_progress =
            run.from_a ? layout.door.x - layout.a.x : layout.b.x - layout.door.x;
        if (policy == evaluation::Policy::kRandom) {
          ++random_runs;
          if (run.trace.passed_door || run.trace.turn) ++random_tried_short;
          if (open) {
            EXPECT_TRUE(run.run_class == evaluation::RunClass::kShort ||
                        run.run_class == evaluation::RunClass::kUnnecessaryDirectLong);
          } else if (run.trace.turn) {
            // It sees the closed door from 6 cells (range_max 3 m, 0.5 m cells) and turns
            // back there: it goes no further than it must to find the door closed.
            EXPECT_EQ(run.run_class, evaluation::RunClass::kIndirectLong);
            EXPECT_EQ(run.trace.turn->progress, door_progress - 6);
            EXPECT_EQ(run.steps, 2 * run.trace.turn->progress + layout.long_path_cells);
          } else {
            EXPECT_EQ(run.run_class, evaluation::RunClass::kLong);
          }
        } else if (open) {
          // Every map shows the door open, and the optimal policy knows it stays so.
          EXPECT_EQ(run.run_class, evaluation::RunClass::kShort);
          EXPECT_EQ(run.steps, layout.short_path_cells);
        } else if (policy != evaluation::Policy::kOnline) {
          // Seen closed during exploration and known not to change (the static grid never
          // forgets, offline EM learned it, the optimal policy knows it): never tried again.
          // (Online learning from 4 exploration loops is not expected to know it yet.)
          EXPECT_EQ(run.run_class, evaluation::RunClass::kLong);
          EXPECT_FALSE(run.trace.turn.has_value());
          // A step may be lost where this short exploration left a corridor cell briefly
          // shown occupied; a detour through the corridor would cost at least 2.
          EXPECT_GE(run.steps, layout.long_path_cells);
          EXPECT_LE(run.steps, layout.long_path_cells + 1);
        }
      }
    }
  }
  // The seed gives both cases, or the test proves less than it claims.
  EXPECT_GT(open_repetitions, 0);
  EXPECT_GT(closed_repetitions, 0);
  // The random policy tries the short path with probability 1/2 on each of 60 runs: 30 on
  // average, standard deviation 3.9; the bounds are 3.8 standard deviations wide.
  EXPECT_EQ(random_runs, 60);
  EXPECT_GE(random_tried_short, 15);
  EXPECT_LE(random_tried_short, 45);
}

TEST(PathPlanningExperiment, RandomPolicyChoosesEachPathHalfTheTime) {
  evaluation::PathPlanningConfig config = smallConfig();
  config.policies = {evaluation::Policy::kRandom};
  config.repetitions = 4;
  config.runs = 100;
  config.idle_steps = 0;
  const evaluation::PathPlanningResult result = evaluation::runPathPlanningExperiment(frozenDoor(), config);
  int tried_short = 0;
  int runs = 0;
  int longest_streak = 0;
  for (const std::vector<evaluation::RunRecord>& repetition : result.runs[0]) {
    int streak = 0;
    bool previous = false;
    for (const evaluation::RunRecord& run : repetition) {
      const bool short_choice = run.trace.passed_door || run.trace.turn.has_value();
      tried_short += short_choice ? 1 : 0;
      ++runs;
      streak = (runs > 1 && short_choice == previous) ? streak + 1 : 1;
      longest_streak = std::max(longest_streak, streak);
      previous = short_choice;
    }
  }
  // 400 fair coin flips: 200 +- 10 (one standard deviation); bounds at 4 standard deviations.
  EXPECT_EQ(runs, 400);
  EXPECT_GE(tried_short, 160);
  EXPECT_LE(tried_short, 240);
  // Independent flips: a run of 20 equal choices in 100 has probability below 1e-4.
  EXPECT_LT(longest_streak, 20);
}

// ---- reproducibility --------------------------------------------------------------------

TEST(PathPlanningExperiment, ResultsDoNotDependOnTheThreadCount) {
  const evaluation::ScenarioConfig door = evaluation::scenarioConfig("door");
  evaluation::PathPlanningConfig config = smallConfig();
  config.repetitions = 3;
  config.runs = 6;
  config.idle_steps = 200;
  config.threads = 1;
  const evaluation::PathPlanningResult one = evaluation::runPathPlanningExperiment(door, config);
  config.threads = 3;
  const evaluation::PathPlanningResult three = evaluation::runPathPlanningExperiment(door, config);
  for (std::size_t p = 0; p < config.policies.size(); ++p) {
    for (std::size_t r = 0; r < 3; ++r) {
      EXPECT_TRUE(sameRuns(one.runs[p][r], three.runs[p][r])) << evaluation::policyName(config.policies[p]) << " " << r;
    }
  }
}

TEST(PathPlanningExperiment, SeedsReproduceAndOtherSeedsDiffer) {
  const evaluation::ScenarioConfig door = evaluation::scenarioConfig("door");
  evaluation::PathPlanningConfig config = smallConfig();
  config.repetitions = 2;
  config.runs = 6;
  config.idle_steps = 200;
  const evaluation::PathPlanningResult first = evaluation::runPathPlanningExperiment(door, config);
  const evaluation::PathPlanningResult again = evaluation::runPathPlanningExperiment(door, config);
  config.seed += 1;
  const evaluation::PathPlanningResult other = evaluation::runPathPlanningExperiment(door, config);
  bool any_difference = false;
  for (std::size_t p = 0; p < config.policies.size(); ++p) {
    for (std::size_t r = 0; r < 2; ++r) {
      EXPECT_TRUE(sameRuns(first.runs[p][r], again.runs[p][r]));
      any_difference = any_difference || !sameRuns(first.runs[p][r], other.runs[p][r]);
    }
  }
  EXPECT_TRUE(any_difference);
  EXPECT_EQ(first.exploration[0].door_changes, again.exploration[0].door_changes);
}

TEST(PathPlanningExperiment, APolicysRunsDoNotDependOnWhichOthersRun) {
  // Every policy has its own simulation with the same seeds, and the random policy its own
  // coin: running it alone changes nothing.
  const evaluation::ScenarioConfig door = evaluation::scenarioConfig("door");
  evaluation::PathPlanningConfig config = smallConfig();
  config.repetitions = 2;
  config.runs = 6;
  config.idle_steps = 200;
  const evaluation::PathPlanningResult all = evaluation::runPathPlanningExperiment(door, config);
  for (const evaluation::Policy policy : {evaluation::Policy::kRandom, evaluation::Policy::kOffline}) {
    config.policies = {policy};
    const evaluation::PathPlanningResult alone = evaluation::runPathPlanningExperiment(door, config);
    for (std::size_t r = 0; r < 2; ++r) {
      EXPECT_TRUE(sameRuns(all.runs[indexOf(all, policy)][r], alone.runs[0][r])) << evaluation::policyName(policy);
    }
  }
}

// ---- configuration, statistics, the paper's table ---------------------------------------

TEST(PathPlanningExperiment, RejectsBadConfigurations) {
  const evaluation::ScenarioConfig door = evaluation::scenarioConfig("door");
  const auto rejects = [&door](const evaluation::PathPlanningConfig& config) {
    EXPECT_THROW(evaluation::runPathPlanningExperiment(door, config), std::invalid_argument);
  };
  evaluation::PathPlanningConfig config;
  config.repetitions = 0;
  rejects(config);
  config = evaluation::PathPlanningConfig();
  config.runs = 0;
  rejects(config);
  config = evaluation::PathPlanningConfig();
  config.idle_steps = -1;
  rejects(config);
  config = evaluation::PathPlanningConfig();
  config.policies.clear();
  rejects(config);
  config = evaluation::PathPlanningConfig();
  config.policies = {evaluation::Policy::kStatic, evaluation::Policy::kStatic};
  rejects(config);
  EXPECT_THROW(evaluation::runPathPlanningExperiment(evaluation::scenarioConfig("parking_lot"), smallConfig()),
               std::invalid_argument);
}

TEST(PathPlanningResult, MeanAndSampleStandardDeviationOverRepetitions) {
  evaluation::PathPlanningResult result;
  result.policies = {evaluation::Policy::kOffline};
  evaluation::RunRecord short_run;
  short_run.run_class = evaluation::RunClass::kShort;
  evaluation::RunRecord long_run;
  long_run.run_class = evaluation::RunClass::kLong;
  evaluation::RunRecord detour;
  detour.run_class = evaluation::RunClass::kIndirectLong;
  // Repetition 0: 1 short of 2; repetition 1: 2 short of 2.
  result.runs = {{{short_run, detour}, {short_run, short_run}}};
  const evaluation::MeanStd percent = result.classPercent(evaluation::Policy::kOffline, evaluation::RunClass::kShort);
  EXPECT_DOUBLE_EQ(percent.mean, 75.0);
  EXPECT_NEAR(percent.std, std::sqrt(2.0) * 25.0, 1e-12);  // values 50, 100: sample std 35.36
  // Effectiveness counts long runs too.
  result.runs = {{{short_run, long_run}, {detour, long_run}}};
  EXPECT_DOUBLE_EQ(result.effectiveness(evaluation::Policy::kOffline).mean, 75.0);
  EXPECT_THROW(result.classPercent(evaluation::Policy::kStatic, evaluation::RunClass::kShort), std::invalid_argument);
}

TEST(PaperTable1, TranscriptionIsConsistent) {
  for (const evaluation::Policy policy : evaluation::kAllPolicies) {
    SCOPED_TRACE(evaluation::policyName(policy));
    // Effectiveness is short + long.
    const double effectiveness = evaluation::paperTable1(policy, evaluation::RunClass::kShort)->mean +
                                 evaluation::paperTable1(policy, evaluation::RunClass::kLong)->mean;
    EXPECT_NEAR(effectiveness, evaluation::paperEffectiveness(policy).mean, 1e-9);
    EXPECT_FALSE(evaluation::paperTable1(policy, evaluation::RunClass::kTimeout).has_value());
    // Each column sums to 100 % where every entry is legible.
    if (policy == evaluation::Policy::kStatic) continue;
    double sum = 0.0;
    for (const evaluation::RunClass run_class : evaluation::kAllRunClasses) {
      if (run_class != evaluation::RunClass::kTimeout) sum += evaluation::paperTable1(policy, run_class)->mean;
    }
    EXPECT_NEAR(sum, 100.0, 1e-9);
  }
  EXPECT_FALSE(
      evaluation::paperTable1(evaluation::Policy::kStatic, evaluation::RunClass::kUnnecessaryIndirectLong).has_value());
  EXPECT_DOUBLE_EQ(evaluation::paperEffectiveness(evaluation::Policy::kOffline).mean, 55.75);
}

TEST(PathPlanningTable, ShowsOursNextToThePaper) {
  evaluation::PathPlanningResult result;
  result.policies = {evaluation::Policy::kOffline};
  evaluation::RunRecord short_run;
  result.runs = {{{short_run}}};
  const std::string table = evaluation::formatPathPlanningTable(result);
  EXPECT_NE(table.find("offline"), std::string::npos);
  EXPECT_NE(table.find("unnecessary direct long"), std::string::npos);
  EXPECT_NE(table.find("100.00"), std::string::npos);  // ours: all short
  EXPECT_NE(table.find("(40.75 ± 20.15)"), std::string::npos);
  EXPECT_NE(table.find("(55.75 ± 13.21)"), std::string::npos);
}
