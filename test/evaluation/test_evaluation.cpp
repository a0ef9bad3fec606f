// The evaluation: methods side by side, accuracy, parameter errors, offline training, and
// the experiment runner.
#include "dynamic_occupancy_grid/evaluation/evaluation.h"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>

namespace dynamic_occupancy_grid {
namespace evaluation {
namespace {

ScenarioConfig shortScenario(const std::string& name, std::int64_t steps) {
  ScenarioConfig config = scenarioConfig(name);
  config.steps = steps;
  return config;
}

// With A = I (a static world and the true, zero transitions) the HMM filter is Bayes' rule
// on a constant state: the oracle's belief must be the unclamped log-odds grid's.
TEST(MethodMappers, OracleOfAStaticWorldIsTheTextbookGrid) {
  ScenarioConfig config = shortScenario("dynamic_5_5", 60);
  config.dynamic_fraction = 0.0;
  Simulation simulation(config, 1, 2);
  MethodMappers mappers(evaluationMapperConfig(config), simulation.world());
  mappers.setOracle(simulation.world());
  for (int t = 0; t < config.steps; ++t) {
    mappers.integrate(simulation.scan());
    mappers.finishStep();
    simulation.advance();
  }
  std::size_t compared = 0;
  for (std::int32_t y = 0; y < config.height_cells; ++y) {
    for (std::int32_t x = 0; x < config.width_cells; ++x) {
      const double oracle = mappers.belief(Method::kOracle, x, y);
      const double textbook = mappers.belief(Method::kStaticUnclamped, x, y);
      ASSERT_EQ(std::isnan(oracle), std::isnan(textbook));
      if (std::isnan(oracle)) continue;
      // Both in float; beliefs saturate at 0/1 where log-odds keep growing.
      ASSERT_NEAR(oracle, textbook, 1e-5) << x << ", " << y;
      ++compared;
    }
  }
  EXPECT_GT(compared, 1000U);
  // The clamped static layer is a different grid: it forgets. A wall cell in front of the
  // robot, seen every step, is far past the clamp in the textbook grid.
  const double clamped = mappers.belief(Method::kStatic, 25, 0);
  const double textbook = mappers.belief(Method::kStaticUnclamped, 25, 0);
  ASSERT_FALSE(std::isnan(clamped));
  ASSERT_FALSE(std::isnan(textbook));
  EXPECT_NEAR(clamped, core::logOddsToProbability(evaluationMapperConfig(config).static_clamp.max_log_odds), 1e-6);
  EXPECT_GT(textbook, clamped);
}

TEST(MethodMappers, OracleAndOfflineUseTheTransitionsTheyAreGiven) {
  const ScenarioConfig config = shortScenario("dynamic_25_25", 30);
  Simulation simulation(config, 3, 4);
  MethodMappers mappers(evaluationMapperConfig(config), simulation.world());
  mappers.setOracle(simulation.world());
  Simulation training(config, 3, 5);
  const core::MapperConfig mapper_config = evaluationMapperConfig(config);
  const OfflineTraining offline = trainOffline(training, mapper_config, 30, evaluationOfflineEmConfig(mapper_config));
  mappers.setOffline(offline);
  for (int t = 0; t < config.steps; ++t) {
    mappers.integrate(simulation.scan());
    mappers.finishStep();
    simulation.advance();
  }
  // The oracle's parameter error is float rounding only.
  const ParameterError oracle = parameterErrorOf(mappers, Method::kOracle, simulation.world());
  EXPECT_GT(oracle.dynamic_cells, 100U);
  EXPECT_GT(oracle.static_cells, 1000U);
  EXPECT_LT(oracle.dynamic_p_occ_given_free + oracle.dynamic_p_free_given_occ, 1e-7);
  EXPECT_LT(oracle.static_p_occ_given_free + oracle.static_p_free_given_occ, 1e-7);
  // Offline: the trained cells carry the EM result.
  std::size_t checked = 0;
  for (std::size_t i = 0; i < offline.sequences.cellCount(); ++i) {
    const core::CellXY c = offline.sequences.cell(i);
    const std::optional<core::TransitionParams> used = mappers.transitions(Method::kOffline, c.x, c.y);
    if (!used) continue;  // not observed in the evaluation run
    EXPECT_NEAR(used->p_occ_given_free, offline.result.params[i].p_occ_given_free, 1e-7);
    EXPECT_NEAR(used->p_free_given_occ, offline.result.params[i].p_free_given_occ, 1e-7);
    ++checked;
  }
  EXPECT_GT(checked, 1000U);
  EXPECT_THROW(mappers.transitions(Method::kStatic, 1, 1), std::invalid_argument);
}

TEST(MethodMappers, RefusesAMapperThatIsNotOnTheWorld) {
  const ScenarioConfig config = scenarioConfig("dynamic_5_5");
  Simulation simulation(config, 1, 1);
  core::MapperConfig mapper_config = evaluationMapperConfig(config);
  mapper_config.fixed_bounds = false;
  EXPECT_THROW(MethodMappers(mapper_config, simulation.world()), std::invalid_argument);
}

TEST(Accuracy, CountsClassifiedCellsOnlyAndHonoursTheMask) {
  const ScenarioConfig config = shortScenario("dynamic_5_5", 3);
  Simulation simulation(config, 7, 8);
  MethodMappers mappers(evaluationMapperConfig(config), simulation.world());
  // Nothing observed yet: nothing classified.
  EXPECT_EQ(accuracyOf(mappers, Method::kOnline, simulation.world()).classified, 0U);
  EXPECT_EQ(accuracyOf(mappers, Method::kOnline, simulation.world()).value(), 0.0);
  mappers.integrate(simulation.scan());
  mappers.finishStep();
  std::size_t observed = 0;
  std::size_t correct = 0;
  std::vector<std::uint8_t> mask(simulation.world().occupancy().size(), 0);
  std::size_t masked_observed = 0;
  for (std::int32_t y = 0; y < config.height_cells; ++y) {
    for (std::int32_t x = 0; x < config.width_cells; ++x) {
      const double p = mappers.belief(Method::kOnline, x, y);
      if (std::isnan(p)) continue;
      ASSERT_NE(p, 0.5);
      ++observed;
      correct += (p > 0.5) == simulation.world().occupied(x, y);
      if (x < 25) {
        mask[simulation.world().index(x, y)] = 1;
        ++masked_observed;
      }
    }
  }
  const Accuracy all = accuracyOf(mappers, Method::kOnline, simulation.world());
  EXPECT_EQ(all.classified, observed);
  EXPECT_EQ(all.correct, correct);
  EXPECT_LT(observed, static_cast<std::size_t>(config.width_cells * config.height_cells));
  EXPECT_EQ(accuracyOf(mappers, Method::kOnline, simulation.world(), &mask).classified, masked_observed);
  const std::vector<std::uint8_t> wrong_size(3, 1);
  EXPECT_THROW(accuracyOf(mappers, Method::kOnline, simulation.world(), &wrong_size), std::invalid_argument);
}

// EM against known parameters: cells changing with 0.1 per step, observed most steps.
TEST(TrainOffline, LearnsTheTrueTransitionsOfWellObservedCells) {
  ScenarioConfig config = shortScenario("dynamic_5_5", 2000);
  config.change_probability = 0.1;
  Simulation training(config, 9, 10);
  core::MapperConfig mapper_config = evaluationMapperConfig(config);
  // The laser's measured per-beam rates (SensorModelIsNoMoreCertainThanTheLaser): with the
  // scenario's deliberately less certain model EM would explain part of the changes as
  // sensor noise and learn rates biased low.
  mapper_config.p_hit_given_occ = 0.98;
  mapper_config.p_hit_given_free = 0.01;
  const OfflineTraining offline = trainOffline(training, mapper_config, config.steps, evaluationOfflineEmConfig(mapper_config));
  double sum_of = 0.0;
  double sum_fo = 0.0;
  double sum_static = 0.0;
  int dynamic = 0;
  int statics = 0;
  for (std::size_t i = 0; i < offline.sequences.cellCount(); ++i) {
    const core::CellXY c = offline.sequences.cell(i);
    const auto observed = offline.sequences.end(i) - offline.sequences.begin(i);
    if (observed < 1000) continue;
    if (training.world().isDynamic(c.x, c.y)) {
      sum_of += offline.result.params[i].p_occ_given_free;
      sum_fo += offline.result.params[i].p_free_given_occ;
      ++dynamic;
    } else if (!training.world().occupied(c.x, c.y)) {
      sum_static += offline.result.params[i].p_occ_given_free;
      ++statics;
    }
  }
  ASSERT_GT(dynamic, 20);
  ASSERT_GT(statics, 200);
  EXPECT_NEAR(sum_of / dynamic, 0.1, 0.015);
  EXPECT_NEAR(sum_fo / dynamic, 0.1, 0.015);
  // Truly static free cells: below the prior guess of 0.01 (the truth is 0; the prior
  // pseudo-counts keep it off the bound).
  EXPECT_LT(sum_static / statics, 0.008);
}

TEST(AccuracyExperiment, ReproducibleAndIndependentOfThreads) {
  const ScenarioConfig config = shortScenario("redraw_100", 150);
  AccuracyExperimentConfig one;
  one.repetitions = 3;
  one.threads = 1;
  AccuracyExperimentConfig two = one;
  two.threads = 2;
  int calls = 0;
  const AccuracyExperimentResult a = runAccuracyExperiment(config, one, [&calls](int done) { calls = done; });
  const AccuracyExperimentResult b = runAccuracyExperiment(config, two);
  EXPECT_EQ(calls, 3);
  EXPECT_EQ(a.accuracy, b.accuracy);
  ASSERT_EQ(a.accuracy[0].size(), 3U);
  ASSERT_EQ(a.accuracy[0][0].size(), 150U);
  EXPECT_NE(a.accuracy[0][0], a.accuracy[0][1]);  // repetitions differ
  AccuracyExperimentConfig other_seed = one;
  other_seed.seed = 2;
  EXPECT_NE(runAccuracyExperiment(config, other_seed).accuracy, a.accuracy);
  EXPECT_EQ(a.online_error.size(), 3U);
  AccuracyExperimentConfig none = one;
  none.repetitions = 0;
  EXPECT_THROW(runAccuracyExperiment(config, none), std::invalid_argument);
}

// The oracle is the best any learner can do, and the dynamic grid beats the static layer
// once the dynamic cells matter (25 % of them, changing every fourth step).
TEST(AccuracyExperiment, OracleLeadsAndDynamicBeatsStatic) {
  const ScenarioConfig config = shortScenario("dynamic_25_25", 400);
  AccuracyExperimentConfig experiment;
  experiment.repetitions = 2;
  const AccuracyExperimentResult result = runAccuracyExperiment(config, experiment);
  const auto mean = [&](Method method) {
    double sum = 0.0;
    int n = 0;
    for (std::size_t m = 0; m < kAllMethods.size(); ++m) {
      if (kAllMethods[m] != method) continue;
      for (const auto& series : result.accuracy[m]) {
        for (std::size_t t = 200; t < series.size(); ++t, ++n) sum += series[t];
      }
    }
    return sum / n;
  };
  EXPECT_GT(mean(Method::kOracle), mean(Method::kOnline));
  EXPECT_GT(mean(Method::kOracle), mean(Method::kOffline));
  EXPECT_GT(mean(Method::kOnline), mean(Method::kStatic));
  EXPECT_GT(mean(Method::kOnline), mean(Method::kStaticUnclamped));
  EXPECT_GT(mean(Method::kOffline), mean(Method::kStatic) + 0.01);
}

// Without the per-hour mask, unseen car interiors made every method look wrong; with it the
// oracle stays near-perfect through the hours.
TEST(AccuracyExperiment, ParkingLotCountsOnlyCellsSeenThisHour) {
  ScenarioConfig config = scenarioConfig("parking_lot");
  config.steps = 4 * config.steps_per_hour;
  AccuracyExperimentConfig experiment;
  experiment.repetitions = 1;
  const AccuracyExperimentResult result = runAccuracyExperiment(config, experiment);
  const std::vector<double>& oracle = result.accuracy[4][0];
  for (std::int64_t hour = 0; hour < 4; ++hour) {
    double sum = 0.0;
    for (std::int64_t t = hour * config.steps_per_hour; t < (hour + 1) * config.steps_per_hour; ++t) {
      const double value = oracle[static_cast<std::size_t>(t)];
      // The first sight of a new car needs a step or two to be believed.
      EXPECT_GT(value, 0.9) << "step " << t;
      sum += value;
    }
    EXPECT_GT(sum / config.steps_per_hour, 0.99) << "hour " << hour;
  }
}

}  // namespace
}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
