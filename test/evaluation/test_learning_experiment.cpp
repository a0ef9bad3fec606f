// Tests of the patrol scenario (evaluation/simulator.h, PatrolLayout) and of the learning
// experiment (evaluation/learning_experiment.h).
#include "dynamic_occupancy_grid/evaluation/learning_experiment.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <set>
#include <stdexcept>
#include <string>

namespace dog = dynamic_occupancy_grid::core;
namespace evaluation = dynamic_occupancy_grid::evaluation;

// The layout: 4 doors, 4 carts, 6 people spots, each a group of cells with its kind's truth,
// changing as one, off the robot's loop.
TEST(PatrolScenario, PartsChangeAsGroupsWithTheirKindsRates) {
  evaluation::ScenarioConfig config = evaluation::scenarioConfig("patrol");
  evaluation::Simulation simulation(config, 11, 12);
  const evaluation::PatrolLayout& layout = simulation.patrolLayout();
  std::size_t doors = 0, carts = 0, people = 0;
  for (const auto& part : layout.parts) {
    doors += part.kind == "door";
    carts += part.kind == "cart";
    people += part.kind == "person";
    const dog::TransitionParams expected = part.kind == "door"   ? config.patrol_door
                                           : part.kind == "cart" ? config.patrol_cart
                                                                 : config.patrol_person;
    for (const dog::CellXY& c : part.cells) {
      EXPECT_EQ(simulation.world().truth(c.x, c.y).p_occ_given_free, expected.p_occ_given_free);
      EXPECT_EQ(simulation.world().truth(c.x, c.y).p_free_given_occ, expected.p_free_given_occ);
    }
  }
  EXPECT_EQ(doors, 4u);
  EXPECT_EQ(carts, 4u);
  EXPECT_EQ(people, 6u);
  // Over many steps every part's cells agree at every step, and the people spots change
  // about as often as their rates say (stationary share of occupied steps 0.12 / 0.37).
  double person_occupied = 0.0, person_steps = 0.0;
  for (int t = 0; t < 3000; ++t) {
    for (const auto& part : layout.parts) {
      const bool first = simulation.world().occupied(part.cells[0].x, part.cells[0].y);
      for (const dog::CellXY& c : part.cells) ASSERT_EQ(simulation.world().occupied(c.x, c.y), first);
      if (part.kind == "person") {
        person_occupied += first ? 1.0 : 0.0;
        person_steps += 1.0;
      }
    }
    simulation.advance();
  }
  EXPECT_NEAR(person_occupied / person_steps, 0.12 / 0.37, 0.05);
  // The robot never drives through a part: every pose of a loop is 0.3 m clear of them.
  for (double s = 0.0; s < 112.0; s += 0.25) {
    const dog::Pose2D pose = evaluation::LoopPath({{2.5, 2.5}, {21.5, 2.5}, {21.5, 11.5}, {2.5, 11.5}}, 0.5).poseAt(s);
    for (const auto& part : layout.parts) {
      for (const dog::CellXY& c : part.cells) {
        const double dx = (c.x + 0.5) * 0.1 - pose.x_m;
        const double dy = (c.y + 0.5) * 0.1 - pose.y_m;
        ASSERT_GT(dx * dx + dy * dy, 0.3 * 0.3) << part.kind;
      }
    }
  }
  EXPECT_THROW(evaluation::Simulation(evaluation::scenarioConfig("door"), 1, 2).patrolLayout(), std::logic_error);
}

// A short patrol: every method is scored, the oracle's parameters are exact, the static map
// keeps itself, learning off (symmetric 0.01 prior) forgets the places the robot left while
// the default learner keeps them, and the measured laser matches the scenario's sensor model.
TEST(LearningExperiment, ScoresEveryMethodOnAShortPatrol) {
  evaluation::ScenarioConfig scenario = evaluation::scenarioConfig("patrol");
  scenario.steps = 400;
  evaluation::LearningExperimentConfig config;
  config.repetitions = 1;
  config.threads = 1;
  const evaluation::LearningExperimentResult result = evaluation::runLearningExperiment(scenario, config);
  std::vector<std::string> names;
  for (const auto& m : result.methods) names.push_back(m.method);
  EXPECT_EQ(names, (std::vector<std::string>{"static", "node_static", "node_default", "textbook", "learning_off",
                                             "default", "cell_em", "offline", "oracle"}));
  const auto& oracle = result.method("oracle");
  EXPECT_NEAR(oracle.dynamic_mae[0], 0.0, 1e-7);  // the truth, rounded to float
  EXPECT_TRUE(result.method("static").kinds.empty());
  EXPECT_TRUE(result.method("node_static").kinds.empty());
  // Every method scores each kind of cell it classified.
  for (const auto& m : result.methods) EXPECT_EQ(m.accuracy_by_kind.count("0.12 / 0.25"), 1U) << m.method;
  std::set<std::string> kinds;
  for (const auto& k : oracle.kinds) kinds.insert(k.kind);
  EXPECT_EQ(kinds, (std::set<std::string>{"static free", "static occupied", "0.004 / 0.012", "0.025 / 0.05",
                                          "0.12 / 0.25"}));
  EXPECT_EQ(result.method("static").retention[0], 1.0);
  EXPECT_LT(result.method("learning_off").retention[0], 0.5);
  EXPECT_GT(result.method("default").retention[0], 0.95);
  EXPECT_GT(result.laser_hit_rate_occ, scenario.p_hit_given_occ);
  EXPECT_LT(result.laser_hit_rate_free, scenario.p_hit_given_free);
  EXPECT_GE(oracle.accuracy_changing[0], result.method("learning_off").accuracy_changing[0]);
  // The sensor model is learned (online and offline) towards the simulated laser's rates.
  for (const char* name : {"default", "offline"}) {
    const auto& m = result.method(name);
    EXPECT_LT(std::abs(m.p_hit_given_occ - result.laser_hit_rate_occ),
              std::abs(scenario.p_hit_given_occ - result.laser_hit_rate_occ) / 2.0)
        << name;
    EXPECT_LT(m.p_hit_given_free, scenario.p_hit_given_free) << name;
  }
  // Where the learners of kinds put each kind of cell: only they report it, every observed
  // cell has a most probable kind, and the shares of the kinds sum to one.
  for (const char* name : {"default", "node_default"}) {
    const auto& m = result.method(name);
    ASSERT_EQ(m.kind_transitions.size(), 1U) << name;
    ASSERT_EQ(m.kind_weights.size(), 1U) << name;
    double weights = 0.0;
    for (const double w : m.kind_weights[0]) weights += w;
    EXPECT_NEAR(weights, 1.0, 1e-9) << name;
    for (const auto& k : m.kinds) {
      double shares = 0.0;
      for (const double share : k.most_probable_kind) shares += share;
      EXPECT_NEAR(shares, 1.0, 1e-9) << name << ' ' << k.kind;
    }
    // The walls and the floor, most of the cells, are in the kind that barely changes.
    for (const char* kind : {"static free", "static occupied"}) {
      const auto k =
          std::find_if(m.kinds.begin(), m.kinds.end(), [&](const evaluation::KindScore& s) { return s.kind == kind; });
      ASSERT_NE(k, m.kinds.end());
      const auto biggest = std::max_element(k->most_probable_kind.begin(), k->most_probable_kind.end());
      const int index = static_cast<int>(biggest - k->most_probable_kind.begin());
      EXPECT_GT(*biggest, 0.9) << name << ' ' << kind;
      EXPECT_LT(m.kind_transitions[0][index].p_occ_given_free, 0.01) << name << ' ' << kind;
      EXPECT_LT(m.kind_transitions[0][index].p_free_given_occ, 0.01) << name << ' ' << kind;
    }
  }
  for (const char* name : {"learning_off", "cell_em", "offline", "oracle"}) {
    EXPECT_TRUE(result.method(name).kind_transitions.empty()) << name;
    for (const auto& k : result.method(name).kinds) {
      for (const double share : k.most_probable_kind) EXPECT_EQ(share, 0.0) << name;
    }
  }
  EXPECT_THROW(result.method("nope"), std::invalid_argument);
  config.window_fraction = 0.0;
  EXPECT_THROW(evaluation::runLearningExperiment(scenario, config), std::invalid_argument);
}
