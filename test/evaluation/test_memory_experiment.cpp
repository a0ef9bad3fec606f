// The memory experiment (memory_experiment.h): hypothesis re-weighting after a blocked plan,
// the live layer, and small runs of the protocol on the dividers office.
#include "dynamic_occupancy_grid/evaluation/memory_experiment.h"

#include <gtest/gtest.h>

#include <stdexcept>

namespace dynamic_occupancy_grid {
namespace evaluation {
namespace {

core::MapHypothesis hypothesisOf(std::vector<std::uint32_t> configurations, double weight) {
  core::MapHypothesis h;
  h.configurations = std::move(configurations);
  h.weight = weight;
  return h;
}

// A 10 x 5 room; hypothesis 1 holds a divider across x = 5 with a gap at the top row.
std::vector<BlockedGrid> twoMaps() {
  BlockedGrid open(10, 5);
  BlockedGrid divided(10, 5);
  for (std::int32_t y = 0; y < 4; ++y) divided.setBlocked(5, y, true);
  return {open, divided};
}

TEST(HypothesisSelector, BlockedPlanPrefersTheHypothesisThatPredictedTheObstacle) {
  HypothesisSelector selector(0.1, 10.0);
  selector.setHypotheses({hypothesisOf({}, 0.9), hypothesisOf({1}, 0.1)}, twoMaps());
  const core::CellXY start{0, 0};
  const core::CellXY goal{9, 0};
  std::vector<core::CellXY> plan = selector.select(start, goal, LiveLayer{});
  ASSERT_EQ(selector.actioned(), 0U);  // the heavier map, straight along y = 0
  ASSERT_EQ(plan.size(), 10U);
  // The plan runs into the divider: hypothesis 1 predicted it.
  EXPECT_TRUE(selector.reportObstacles({core::CellXY{5, 0}}));
  EXPECT_NEAR(selector.score(0), 0.09, 1e-12);
  EXPECT_NEAR(selector.score(1), 1.0, 1e-12);
  LiveLayer live;
  live.occupied = {core::CellXY{5, 0}};
  plan = selector.select(start, goal, live);
  EXPECT_EQ(selector.actioned(), 1U);
  EXPECT_EQ(plan.size(), 10U + 8U);  // up to the gap and back down
  // The factors belong to the configuration sets: they survive the memory's next update.
  selector.setHypotheses({hypothesisOf({}, 0.5), hypothesisOf({1}, 0.5)}, twoMaps());
  EXPECT_GT(selector.score(1), selector.score(0));
}

TEST(HypothesisSelector, AnObstacleNoHypothesisPredictedChangesNothing) {
  HypothesisSelector selector(0.1, 10.0);
  selector.setHypotheses({hypothesisOf({}, 0.9), hypothesisOf({1}, 0.1)}, twoMaps());
  selector.select(core::CellXY{0, 0}, core::CellXY{9, 0}, LiveLayer{});
  EXPECT_FALSE(selector.reportObstacles({core::CellXY{2, 0}}));  // a person: neither map holds it
  EXPECT_DOUBLE_EQ(selector.score(0), 0.9);
  EXPECT_DOUBLE_EQ(selector.score(1), 0.1);
  // No hypothesis has a valid plan to a walled-in goal: the best scored is actioned, no plan.
  LiveLayer wall;
  for (std::int32_t y = 0; y < 5; ++y) wall.occupied.push_back(core::CellXY{7, y});
  EXPECT_TRUE(selector.select(core::CellXY{0, 0}, core::CellXY{9, 0}, wall).empty());
  EXPECT_EQ(selector.actioned(), 0U);
  EXPECT_THROW(HypothesisSelector(0.0, 2.0), std::invalid_argument);
  EXPECT_THROW(HypothesisSelector(0.5, 0.5), std::invalid_argument);
}

TEST(LiveLayer, BeamsClearTheCellsTheyCrossAndMarkTheirEnds) {
  World world(10, 5, 1.0);
  world.setStatic(7, 2, true);
  LaserConfig laser;
  laser.beams = 1;
  laser.angle_min_rad = 0.0;
  laser.noise_sigma_m = 0.0;
  laser.dropout_probability = 0.0;
  Rng rng(1);
  const core::Scan scan = simulateScan(world, core::Pose2D{1.5, 2.5, 0.0}, laser, 0.0, rng);
  const LiveLayer layer = LiveLayer::fromScan(scan, 1.0, 10, 5);
  ASSERT_EQ(layer.occupied.size(), 1U);
  EXPECT_EQ(layer.occupied[0], (core::CellXY{7, 2}));
  EXPECT_EQ(layer.free.size(), 6U);  // cells 1..6 of row 2
  BlockedGrid grid(10, 5);
  grid.setBlocked(3, 2, true);  // the map says occupied; the scan saw it free
  layer.applyTo(grid);
  EXPECT_FALSE(grid.blocked(3, 2));
  EXPECT_TRUE(grid.blocked(7, 2));
}

MemoryExperimentConfig smallConfig() {
  MemoryExperimentConfig config;
  config.repetitions = 2;
  config.episodes = 8;
  config.threads = 1;
  return config;
}

// With dividers that never move and nobody walking, every map knows the way after the
// mapping phase: every episode reached, on an optimal path.
TEST(MemoryExperiment, StillOfficeEveryMethodReachesEveryGoalOptimally) {
  ScenarioConfig scenario = scenarioConfig("dividers");
  scenario.divider_toggle_probability = 0.0;
  scenario.people = 0;
  const MemoryExperimentResult result = runMemoryExperiment(scenario, smallConfig());
  for (const NavigationMethod method : kAllNavigationMethods) {
    EXPECT_DOUBLE_EQ(result.goalReachedPercent(method).mean, 100.0) << navigationMethodName(method);
    EXPECT_LE(result.pathRatio(method).mean, 1.0 + 1e-12) << navigationMethodName(method);
    EXPECT_DOUBLE_EQ(result.replansPerEpisode(method).mean, 0.0) << navigationMethodName(method);
  }
  for (const MemoryRepetition& r : result.repetitions) {
    EXPECT_EQ(r.divider_moves, 0);
    EXPECT_EQ(r.people_in_ltm, 0U);
  }
}

// Fast people stay out of LTM, slow dividers get in, and the results do not depend on the
// number of threads.
TEST(MemoryExperiment, PeopleNeverReachLtmDividersDoAndThreadsDoNotMatter) {
  ScenarioConfig scenario = scenarioConfig("dividers");
  scenario.divider_toggle_probability = 0.5;
  MemoryExperimentConfig config = smallConfig();
  const MemoryExperimentResult one = runMemoryExperiment(scenario, config);
  std::size_t divider_cells = 0;
  std::int64_t moves = 0;
  for (const MemoryRepetition& r : one.repetitions) {
    EXPECT_EQ(r.people_in_ltm, 0U);
    divider_cells += r.divider_cells_in_ltm;
    moves += r.divider_moves;
  }
  EXPECT_GT(moves, 0);
  EXPECT_GT(divider_cells, 0U);
  config.threads = 2;
  const MemoryExperimentResult two = runMemoryExperiment(scenario, config);
  for (std::size_t r = 0; r < one.repetitions.size(); ++r) {
    for (std::size_t m = 0; m < kAllNavigationMethods.size(); ++m) {
      const auto& a = one.repetitions[r].episodes[m];
      const auto& b = two.repetitions[r].episodes[m];
      ASSERT_EQ(a.size(), b.size());
      for (std::size_t e = 0; e < a.size(); ++e) {
        EXPECT_EQ(a[e].reached, b[e].reached);
        EXPECT_EQ(a[e].moves, b[e].moves);
        EXPECT_EQ(a[e].optimal, b[e].optimal);
        EXPECT_EQ(a[e].replans, b[e].replans);
      }
    }
    EXPECT_EQ(one.repetitions[r].divider_cells_in_ltm, two.repetitions[r].divider_cells_in_ltm);
    EXPECT_EQ(one.repetitions[r].memory_updates, two.repetitions[r].memory_updates);
  }
}

// The same office with one update per scan's worth of travel: a person's cell seen in two
// consecutive views migrates. The judge must see it (the count is not trivially zero).
TEST(MemoryExperiment, ShortViewsLetPeopleIntoLtmAndTheJudgeCountsThem) {
  ScenarioConfig scenario = scenarioConfig("dividers");
  scenario.people = 8;
  MemoryExperimentConfig config = smallConfig();
  config.memory.update_distance_m = 0.2;  // one step per view
  const MemoryExperimentResult result = runMemoryExperiment(scenario, config);
  std::size_t people = 0;
  for (const MemoryRepetition& r : result.repetitions) people += r.people_in_ltm;
  EXPECT_GT(people, 0U);
}

TEST(MemoryExperiment, RejectsBadConfigurations) {
  MemoryExperimentConfig config;
  EXPECT_THROW(runMemoryExperiment(scenarioConfig("door"), config), std::invalid_argument);
  config.episodes = 0;
  EXPECT_THROW(runMemoryExperiment(scenarioConfig("dividers"), config), std::invalid_argument);
  config.episodes = 1;
  config.penalty = 2.0;
  EXPECT_THROW(runMemoryExperiment(scenarioConfig("dividers"), config), std::invalid_argument);
}

}  // namespace
}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
