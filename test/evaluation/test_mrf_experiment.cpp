// The MRF experiment (Li, Barão & Rato's simulation as a measurement): its RMSE on a case
// worked by hand, reproducibility, independence of the number of threads, and that the MRF
// run is the smoothed one. Whether the MRF meets the targets is what `evaluate`
// measures and reports; it is not asserted here (on this scenario it does not hold for both
// parameters, see the evaluation's summary).
#include "dynamic_occupancy_grid/evaluation/mrf_experiment.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>

namespace dynamic_occupancy_grid {
namespace core {
namespace {

TEST(TransitionRmse, SplitsBySampleCountAndAveragesSquares) {
  World world(4, 1, 1.0);
  world.setScheduled(0, 0, TransitionParams{0.1, 0.2}, true);
  world.setScheduled(1, 0, TransitionParams{0.3, 0.3}, false);
  // (2, 0) and (3, 0) static: truth {0, 0}.
  SequenceBuilder builder;
  // Cells 0 and 2 observed on 2 steps (sparse below 3), cells 1 and 3 on 3 (well observed);
  // several readings in one step are one observed step.
  for (const std::int32_t step : {0, 5}) {
    builder.add(0, 0, step, 1, 0);
    builder.add(2, 0, step, 0, 2);
    builder.add(2, 0, step, 0, 1);
  }
  for (const std::int32_t step : {1, 2, 7}) {
    builder.add(1, 0, step, 0, 1);
    builder.add(3, 0, step, 1, 1);
  }
  const ObservationSequences sequences = builder.build();
  ASSERT_EQ(sequences.cellCount(), 4U);
  // In the order of first appearance: (0,0), (2,0), (1,0), (3,0).
  const std::vector<TransitionParams> learned{{0.1, 0.5}, {0.03, 0.04}, {0.2, 0.3}, {0.0, 0.01}};
  const SplitRmse rmse = transitionRmse(sequences, learned, world, 3);
  EXPECT_EQ(rmse.sparse.cells, 2U);
  EXPECT_NEAR(rmse.sparse.p_occ_given_free, std::sqrt((0.0 * 0.0 + 0.03 * 0.03) / 2.0), 1e-15);
  EXPECT_NEAR(rmse.sparse.p_free_given_occ, std::sqrt((0.3 * 0.3 + 0.04 * 0.04) / 2.0), 1e-15);
  EXPECT_EQ(rmse.well_observed.cells, 2U);
  EXPECT_NEAR(rmse.well_observed.p_occ_given_free, std::sqrt((0.1 * 0.1 + 0.0) / 2.0), 1e-15);
  EXPECT_NEAR(rmse.well_observed.p_free_given_occ, std::sqrt((0.0 + 0.01 * 0.01) / 2.0), 1e-15);

  // The threshold is "fewer than": at 2 every cell is well observed, at 4 every cell sparse;
  // an empty set has no error.
  EXPECT_EQ(transitionRmse(sequences, learned, world, 2).sparse.cells, 0U);
  EXPECT_EQ(transitionRmse(sequences, learned, world, 2).sparse.p_free_given_occ, 0.0);
  EXPECT_EQ(transitionRmse(sequences, learned, world, 4).sparse.cells, 4U);

  EXPECT_THROW(transitionRmse(sequences, {learned[0]}, world, 3), std::invalid_argument);
  const World small(2, 1, 1.0);
  EXPECT_THROW(transitionRmse(sequences, learned, small, 3), std::invalid_argument);
}

TEST(TransitionRmse, PerKindOfCell) {
  World world(4, 1, 1.0);
  world.setScheduled(0, 0, TransitionParams{0.1, 0.2}, true);
  world.setScheduled(1, 0, TransitionParams{0.3, 0.3}, false);
  world.setStatic(2, 0, false);
  world.setStatic(3, 0, true);
  EXPECT_EQ(cellKind(world, 0, 0), CellKind::kChanging);
  EXPECT_EQ(cellKind(world, 1, 0), CellKind::kChanging);
  EXPECT_EQ(cellKind(world, 2, 0), CellKind::kStaticFree);
  EXPECT_EQ(cellKind(world, 3, 0), CellKind::kStaticOccupied);
  // A changing cell stays changing in either state.
  world.setState(1, 0, true);
  EXPECT_EQ(cellKind(world, 1, 0), CellKind::kChanging);
  EXPECT_STREQ(cellKindName(CellKind::kStaticOccupied), "static_occupied");
  EXPECT_THROW(cellKind(world, 4, 0), std::invalid_argument);
  EXPECT_THROW(cellKind(world, 0, -1), std::invalid_argument);

  SequenceBuilder builder;
  for (const std::int32_t step : {0, 5}) {  // sparse (below 3)
    builder.add(0, 0, step, 1, 0);
    builder.add(2, 0, step, 0, 1);
  }
  for (const std::int32_t step : {1, 2, 7}) {  // well observed
    builder.add(1, 0, step, 0, 1);
    builder.add(3, 0, step, 1, 0);
  }
  const ObservationSequences sequences = builder.build();
  // Order of first appearance: (0,0), (2,0), (1,0), (3,0).
  const std::vector<TransitionParams> learned{{0.1, 0.5}, {0.03, 0.04}, {0.2, 0.3}, {0.02, 0.01}};
  const std::array<SplitRmse, kCellKinds> by_kind = transitionRmseByKind(sequences, learned, world, 3);
  const SplitRmse& changing = by_kind[static_cast<std::size_t>(CellKind::kChanging)];
  EXPECT_EQ(changing.sparse.cells, 1U);
  EXPECT_NEAR(changing.sparse.p_occ_given_free, 0.0, 1e-15);
  EXPECT_NEAR(changing.sparse.p_free_given_occ, 0.3, 1e-15);
  EXPECT_EQ(changing.well_observed.cells, 1U);
  EXPECT_NEAR(changing.well_observed.p_occ_given_free, 0.1, 1e-15);
  EXPECT_NEAR(changing.well_observed.p_free_given_occ, 0.0, 1e-15);
  const SplitRmse& free = by_kind[static_cast<std::size_t>(CellKind::kStaticFree)];
  EXPECT_EQ(free.sparse.cells, 1U);
  EXPECT_NEAR(free.sparse.p_occ_given_free, 0.03, 1e-15);
  EXPECT_NEAR(free.sparse.p_free_given_occ, 0.04, 1e-15);
  EXPECT_EQ(free.well_observed.cells, 0U);
  const SplitRmse& occupied = by_kind[static_cast<std::size_t>(CellKind::kStaticOccupied)];
  EXPECT_EQ(occupied.sparse.cells, 0U);
  EXPECT_EQ(occupied.well_observed.cells, 1U);
  EXPECT_NEAR(occupied.well_observed.p_occ_given_free, 0.02, 1e-15);
  EXPECT_NEAR(occupied.well_observed.p_free_given_occ, 0.01, 1e-15);

  EXPECT_THROW(transitionRmseByKind(sequences, {learned[0]}, world, 3), std::invalid_argument);
}

// A short version of the scenario (5 of its 20 loops) keeps the tests quick.
ScenarioConfig shortScenario() {
  ScenarioConfig scenario = scenarioConfig("mrf_squares");
  scenario.steps = 5 * 24;
  return scenario;
}

void expectSameOutcome(const MrfEmOutcome& a, const MrfEmOutcome& b) {
  EXPECT_EQ(a.rmse.sparse.cells, b.rmse.sparse.cells);
  EXPECT_EQ(a.rmse.sparse.p_occ_given_free, b.rmse.sparse.p_occ_given_free);
  EXPECT_EQ(a.rmse.sparse.p_free_given_occ, b.rmse.sparse.p_free_given_occ);
  EXPECT_EQ(a.rmse.well_observed.cells, b.rmse.well_observed.cells);
  EXPECT_EQ(a.rmse.well_observed.p_occ_given_free, b.rmse.well_observed.p_occ_given_free);
  EXPECT_EQ(a.rmse.well_observed.p_free_given_occ, b.rmse.well_observed.p_free_given_occ);
  for (std::size_t k = 0; k < kCellKinds; ++k) {
    for (const auto& [x, y] : {std::make_pair(a.rmse_by_kind[k].sparse, b.rmse_by_kind[k].sparse),
                               std::make_pair(a.rmse_by_kind[k].well_observed, b.rmse_by_kind[k].well_observed)}) {
      EXPECT_EQ(x.cells, y.cells);
      EXPECT_EQ(x.p_occ_given_free, y.p_occ_given_free);
      EXPECT_EQ(x.p_free_given_occ, y.p_free_given_occ);
    }
  }
  EXPECT_EQ(a.em_iterations, b.em_iterations);
  EXPECT_EQ(a.objective, b.objective);
  EXPECT_EQ(a.newton_iterations, b.newton_iterations);
}

// Bitwise equal, NaN matching NaN (cells never observed).
bool sameMap(const std::vector<TransitionParams>& a, const std::vector<TransitionParams>& b) {
  const auto same = [](double x, double y) { return x == y || (std::isnan(x) && std::isnan(y)); };
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (!same(a[i].p_occ_given_free, b[i].p_occ_given_free) || !same(a[i].p_free_given_occ, b[i].p_free_given_occ)) {
      return false;
    }
  }
  return true;
}

TEST(MrfExperiment, ReproducibleAndIndependentOfThreads) {
  MrfExperimentConfig config;
  config.repetitions = 2;
  config.threads = 1;
  const MrfExperimentResult one = runMrfExperiment(shortScenario(), config);
  config.threads = 2;
  const MrfExperimentResult two = runMrfExperiment(shortScenario(), config);
  ASSERT_EQ(one.repetitions.size(), 2U);
  ASSERT_EQ(two.repetitions.size(), 2U);
  for (std::size_t r = 0; r < 2; ++r) {
    EXPECT_EQ(one.repetitions[r].world_seed, two.repetitions[r].world_seed);
    EXPECT_EQ(one.repetitions[r].run_seed, two.repetitions[r].run_seed);
    EXPECT_EQ(one.repetitions[r].cells_observed, two.repetitions[r].cells_observed);
    expectSameOutcome(one.repetitions[r].plain, two.repetitions[r].plain);
    expectSameOutcome(one.repetitions[r].mrf, two.repetitions[r].mrf);
  }
  // Two repetitions are two different runs.
  EXPECT_NE(one.repetitions[0].run_seed, one.repetitions[1].run_seed);
  EXPECT_NE(one.repetitions[0].mrf.objective, one.repetitions[1].mrf.objective);
  EXPECT_EQ(one.first_maps.observed_steps, two.first_maps.observed_steps);
  EXPECT_TRUE(sameMap(one.first_maps.plain, two.first_maps.plain));
  EXPECT_TRUE(sameMap(one.first_maps.mrf, two.first_maps.mrf));
  // Another seed, another experiment.
  config.seed = 2;
  const MrfExperimentResult other = runMrfExperiment(shortScenario(), config);
  EXPECT_NE(other.repetitions[0].run_seed, one.repetitions[0].run_seed);
}

// The sum over 8-neighbour pairs of observed cells of the squared difference of the logits of
// one parameter: what the MRF prior penalises.
double roughness(const MrfMaps& maps, const std::vector<TransitionParams>& map, bool occ_given_free) {
  const auto logit = [&](std::size_t i) {
    const double p = occ_given_free ? map[i].p_occ_given_free : map[i].p_free_given_occ;
    return std::log(p / (1.0 - p));
  };
  double sum = 0.0;
  for (std::int32_t y = 0; y < maps.height; ++y) {
    for (std::int32_t x = 0; x < maps.width; ++x) {
      const std::size_t i = static_cast<std::size_t>(y) * static_cast<std::size_t>(maps.width) + static_cast<std::size_t>(x);
      if (maps.observed_steps[i] == 0) continue;
      // Each pair once: the neighbours right, above-left, above, above-right.
      for (const auto& [dx, dy] : {std::pair{1, 0}, std::pair{-1, 1}, std::pair{0, 1}, std::pair{1, 1}}) {
        const std::int32_t nx = x + dx;
        const std::int32_t ny = y + dy;
        if (nx < 0 || ny >= maps.height || nx >= maps.width) continue;
        const std::size_t j = static_cast<std::size_t>(ny) * static_cast<std::size_t>(maps.width) + static_cast<std::size_t>(nx);
        if (maps.observed_steps[j] == 0) continue;
        sum += (logit(i) - logit(j)) * (logit(i) - logit(j));
      }
    }
  }
  return sum;
}

TEST(MrfExperiment, MapsAndIterationRecordsOfBothEms) {
  MrfExperimentConfig config;
  config.repetitions = 1;
  const MrfExperimentResult result = runMrfExperiment(shortScenario(), config);
  const MrfRepetition& run = result.repetitions.front();
  const MrfMaps& maps = result.first_maps;
  ASSERT_EQ(maps.width, 46);
  ASSERT_EQ(maps.height, 32);
  ASSERT_EQ(maps.truth.size(), 46U * 32U);
  std::size_t observed = 0;
  std::size_t sparse = 0;
  for (std::size_t i = 0; i < maps.truth.size(); ++i) {
    if (maps.observed_steps[i] == 0) {
      EXPECT_TRUE(std::isnan(maps.plain[i].p_occ_given_free) && std::isnan(maps.mrf[i].p_free_given_occ));
      continue;
    }
    ++observed;
    sparse += maps.observed_steps[i] < config.sparse_below;
    for (const TransitionParams& p : {maps.plain[i], maps.mrf[i]}) {
      // Within the EM's bounds [1e-4, 0.5] (the MRF's through logits: up to rounding).
      EXPECT_GE(p.p_occ_given_free, 1e-4 * (1.0 - 1e-9));
      EXPECT_LE(p.p_free_given_occ, 0.5 * (1.0 + 1e-12));
    }
  }
  EXPECT_EQ(observed, run.cells_observed);
  EXPECT_EQ(sparse, run.plain.rmse.sparse.cells);
  EXPECT_EQ(sparse, run.mrf.rmse.sparse.cells);
  EXPECT_EQ(observed - sparse, run.mrf.rmse.well_observed.cells);
  EXPECT_GT(sparse, 0U);

  // The objective before the first M-step and after each; Newton iterations per M-step for
  // the MRF only.
  EXPECT_EQ(run.plain.objective.size(), static_cast<std::size_t>(run.plain.em_iterations) + 1);
  EXPECT_TRUE(run.plain.newton_iterations.empty());
  EXPECT_EQ(run.mrf.objective.size(), static_cast<std::size_t>(run.mrf.em_iterations) + 1);
  ASSERT_EQ(run.mrf.newton_iterations.size(), static_cast<std::size_t>(run.mrf.em_iterations));
  for (const std::array<int, 2>& newton : run.mrf.newton_iterations) {
    EXPECT_GE(newton[0], 0);
    EXPECT_GE(newton[1], 0);
  }
  // Both start from the same point (the paper's 0.5, where the MRF prior is 0) on the same
  // data; the sums run in different orders.
  EXPECT_NEAR(run.plain.objective.front(), run.mrf.objective.front(), 1e-9 * std::abs(run.plain.objective.front()));
  EXPECT_GT(run.plain.em_seconds, 0.0);
  EXPECT_GT(run.mrf.em_seconds, 0.0);

  // The MRF run is the smoothed one: its maps vary less between neighbours, for both parameters.
  for (const bool occ_given_free : {true, false}) {
    EXPECT_LT(roughness(maps, maps.mrf, occ_given_free), 0.5 * roughness(maps, maps.plain, occ_given_free))
        << (occ_given_free ? "p_occ_given_free" : "p_free_given_occ");
  }
}

TEST(MrfExperiment, RejectsBadSettings) {
  MrfExperimentConfig config;
  config.repetitions = 0;
  EXPECT_THROW(runMrfExperiment(shortScenario(), config), std::invalid_argument);
  config.repetitions = 1;
  // Offline EM's own lower bound: a temperature it would refuse is refused up front.
  for (const double temperature : {0.0, -1.0, 1e-10, std::nan(""), std::numeric_limits<double>::infinity()}) {
    MrfExperimentConfig bad = config;
    bad.temperature = temperature;
    EXPECT_THROW(bad.validate(), std::invalid_argument) << temperature;
  }
  MrfExperimentConfig bad = config;
  bad.sparse_below = 0;
  EXPECT_THROW(bad.validate(), std::invalid_argument);
  bad = config;
  bad.max_iterations = 0;
  EXPECT_THROW(bad.validate(), std::invalid_argument);
  ScenarioConfig scenario = shortScenario();
  scenario.square_hold_steps[2] = 0;
  EXPECT_THROW(runMrfExperiment(scenario, config), std::invalid_argument);
}

}  // namespace
}  // namespace core
}  // namespace dynamic_occupancy_grid
