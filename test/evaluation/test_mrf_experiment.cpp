// The MRF experiment (Li, Barão & Rato's simulation as a measurement): its RMSE on a case
// worked by hand (per kind only on the parameters a cell's data carry), the squares seen in
// both states, reproducibility, independence of the number of threads, that the MRF run is
// the smoothed one, and that the online learners (each cell's own online EM without and with
// the empirical-Bayes prior, and kinds of cells) are there and scored. Which method wins
// where is what `evaluate` measures and reports (docs/results.md); it is not asserted here.
#include "dynamic_occupancy_grid/evaluation/mrf_experiment.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <set>
#include <stdexcept>

#include "dynamic_occupancy_grid/core/cell/cell_kinds.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/evaluation/evaluation.h"

namespace dynamic_occupancy_grid {
namespace evaluation {
namespace {

TEST(TransitionRmse, SplitsBySampleCountAndAveragesSquares) {
  World world(4, 1, 1.0);
  world.setScheduled(0, 0, core::TransitionParams{0.1, 0.2}, true);
  world.setScheduled(1, 0, core::TransitionParams{0.3, 0.3}, false);
  // (2, 0) and (3, 0) static: truth {0, 0}.
  core::SequenceBuilder builder;
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
  const core::ObservationSequences sequences = builder.build();
  ASSERT_EQ(sequences.cellCount(), 4U);
  // In the order of first appearance: (0,0), (2,0), (1,0), (3,0).
  const std::vector<core::TransitionParams> learned{{0.1, 0.5}, {0.03, 0.04}, {0.2, 0.3}, {0.0, 0.01}};
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
  world.setScheduled(0, 0, core::TransitionParams{0.1, 0.2}, true);
  world.setScheduled(1, 0, core::TransitionParams{0.3, 0.3}, false);
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

  core::SequenceBuilder builder;
  for (const std::int32_t step : {0, 5}) {  // sparse (below 3)
    builder.add(0, 0, step, 1, 0);
    builder.add(2, 0, step, 0, 1);
  }
  for (const std::int32_t step : {1, 2, 7}) {  // well observed
    builder.add(1, 0, step, 0, 1);
    builder.add(3, 0, step, 1, 0);
  }
  const core::ObservationSequences sequences = builder.build();
  // Order of first appearance: (0,0), (2,0), (1,0), (3,0).
  const std::vector<core::TransitionParams> learned{{0.1, 0.5}, {0.03, 0.04}, {0.2, 0.3}, {0.02, 0.01}};
  // Scored: a changing cell on both parameters, a static free cell on p_occ_given_free only,
  // a static occupied cell on p_free_given_occ only (the other is NaN).
  EXPECT_TRUE(isScored(CellKind::kChanging, true));
  EXPECT_TRUE(isScored(CellKind::kChanging, false));
  EXPECT_TRUE(isScored(CellKind::kStaticFree, true));
  EXPECT_FALSE(isScored(CellKind::kStaticFree, false));
  EXPECT_FALSE(isScored(CellKind::kStaticOccupied, true));
  EXPECT_TRUE(isScored(CellKind::kStaticOccupied, false));
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
  EXPECT_TRUE(std::isnan(free.sparse.p_free_given_occ));  // 0.04 learned: the prior's, not scored
  EXPECT_EQ(free.well_observed.cells, 0U);
  EXPECT_EQ(free.well_observed.p_occ_given_free, 0.0);
  EXPECT_TRUE(std::isnan(free.well_observed.p_free_given_occ));
  const SplitRmse& occupied = by_kind[static_cast<std::size_t>(CellKind::kStaticOccupied)];
  EXPECT_EQ(occupied.sparse.cells, 0U);
  EXPECT_EQ(occupied.well_observed.cells, 1U);
  EXPECT_TRUE(std::isnan(occupied.well_observed.p_occ_given_free));  // 0.02 learned, not scored
  EXPECT_NEAR(occupied.well_observed.p_free_given_occ, 0.01, 1e-15);
  EXPECT_THROW(transitionRmseByKind(sequences, {learned[0]}, world, 3), std::invalid_argument);
}

TEST(TransitionRmse, ChangingCellsByWhatTheirDataShow) {
  World world(3, 1, 1.0);
  world.setScheduled(0, 0, core::TransitionParams{0.1, 0.2}, true);
  world.setScheduled(1, 0, core::TransitionParams{0.3, 0.3}, false);
  world.setStatic(2, 0, false);
  core::SequenceBuilder builder;
  builder.add(0, 0, 0, 2, 0);  // (0, 0): a step of more hits, one of more misses: both states
  builder.add(0, 0, 1, 0, 1);
  builder.add(0, 0, 2, 1, 1);
  builder.add(1, 0, 0, 0, 1);  // (1, 0): misses only (a tie is neither): one state
  builder.add(1, 0, 1, 1, 1);
  builder.add(2, 0, 0, 1, 0);  // static: in neither class
  builder.add(2, 0, 1, 0, 1);
  const core::ObservationSequences sequences = builder.build();
  const std::vector<core::TransitionParams> learned{{0.15, 0.1}, {0.05, 0.5}, {0.2, 0.2}};
  const std::array<SplitRmse, 2> by_data = changingRmseBySeenStates(sequences, learned, world, 4);
  EXPECT_EQ(by_data[0].sparse.cells, 1U);  // 3 observed steps, sparse below 4
  EXPECT_EQ(by_data[0].well_observed.cells, 0U);
  EXPECT_NEAR(by_data[0].sparse.p_occ_given_free, 0.05, 1e-15);
  EXPECT_NEAR(by_data[0].sparse.p_free_given_occ, 0.1, 1e-15);
  EXPECT_EQ(by_data[1].sparse.cells, 1U);
  EXPECT_NEAR(by_data[1].sparse.p_occ_given_free, 0.25, 1e-15);
  EXPECT_NEAR(by_data[1].sparse.p_free_given_occ, 0.2, 1e-15);
  EXPECT_EQ(by_data[1].well_observed.cells, 0U);
  const std::array<SplitRmse, 2> at_3 = changingRmseBySeenStates(sequences, learned, world, 3);
  EXPECT_EQ(at_3[0].well_observed.cells, 1U);
  EXPECT_EQ(at_3[0].sparse.cells, 0U);
  EXPECT_EQ(at_3[1].sparse.cells, 1U);
  EXPECT_THROW(changingRmseBySeenStates(sequences, {learned[0]}, world, 3), std::invalid_argument);
}

TEST(SquareCells, SeenInBothStatesNeedsAStepOfEach) {
  MrfSquaresLayout layout;
  layout.square_side_cells = 2;
  layout.square_corner = {core::CellXY{0, 0}, core::CellXY{4, 0}, core::CellXY{8, 0}, core::CellXY{12, 0}};
  core::SequenceBuilder builder;
  builder.add(0, 0, 0, 2, 1);  // square 0: more hits, then more misses: both
  builder.add(0, 0, 3, 0, 1);
  builder.add(1, 1, 0, 1, 0);  // square 0: hits only
  builder.add(1, 1, 2, 3, 0);
  builder.add(4, 1, 0, 1, 1);  // square 1: a tie is neither, then a miss
  builder.add(4, 1, 1, 0, 2);
  builder.add(5, 0, 0, 0, 1);  // square 1: both, misses first
  builder.add(5, 0, 9, 1, 0);
  builder.add(2, 0, 0, 1, 0);  // between squares 0 and 1: no square's
  builder.add(2, 0, 1, 0, 1);
  builder.add(13, 1, 4, 1, 0);  // square 3: both
  builder.add(13, 1, 5, 0, 3);
  EXPECT_EQ(squareCellsSeenInBothStates(builder.build(), layout), (std::array<std::size_t, 4>{1, 1, 0, 1}));
}

// The scenario's squares are seen in both states: in every run, every square has cells
// (most of its 4-cell face towards the loop) with steps of more hits and steps of more
// misses, not all (the rest is hidden behind the face while it is occupied); and the robot
// meets each square while occupied and while free in many of its 20 loops. Over 100 runs
// a square had 3 to 9 such cells (5 to 7 in 88 % of them), the four squares 21 to 29.
TEST(SquareCells, TheScenariosSquaresAreSeenInBothStates) {
  const ScenarioConfig scenario = scenarioConfig("mrf_squares");
  for (std::uint64_t seed = 1; seed <= 3; ++seed) {
    Simulation simulation(scenario, seed, seed + 100);
    const MrfSquaresLayout layout = simulation.mrfSquaresLayout();
    core::MapperConfig mapper_config = evaluationMapperConfig(scenario);
    mapper_config.learn_transitions = false;
    core::Mapper mapper(mapper_config);
    core::SequenceBuilder recorder;
    mapper.recordObservations(&recorder);
    std::vector<std::array<bool, 4>> occupied;  // per step, the state its scan sees
    for (std::int64_t t = 0; t < scenario.steps; ++t) {
      std::array<bool, 4> now{};
      for (std::size_t k = 0; k < 4; ++k) {
        now[k] = simulation.world().occupied(layout.square_corner[k].x, layout.square_corner[k].y);
      }
      occupied.push_back(now);
      ASSERT_EQ(mapper.integrate(simulation.scan()).status, core::ScanStatus::kIntegrated);
      simulation.advance();
    }
    mapper.finishStep();
    mapper.recordObservations(nullptr);
    const core::ObservationSequences sequences = recorder.build();
    const std::array<std::size_t, 4> both = squareCellsSeenInBothStates(sequences, layout);
    // Per square, the loops in which one of its cells was observed while it was occupied / free.
    std::array<std::set<std::int64_t>, 4> loops_occupied;
    std::array<std::set<std::int64_t>, 4> loops_free;
    for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
      const core::CellXY xy = sequences.cell(c);
      for (std::size_t k = 0; k < 4; ++k) {
        const core::CellXY corner = layout.square_corner[k];
        if (xy.x < corner.x || xy.y < corner.y || xy.x >= corner.x + layout.square_side_cells ||
            xy.y >= corner.y + layout.square_side_cells) {
          continue;
        }
        for (const core::StepObservation* o = sequences.begin(c); o != sequences.end(c); ++o) {
          const std::int64_t loop = o->step / layout.loop_steps;
          (occupied[static_cast<std::size_t>(o->step)][k] ? loops_occupied[k] : loops_free[k]).insert(loop);
        }
      }
    }
    EXPECT_GE(both[0] + both[1] + both[2] + both[3], 20U) << "seed " << seed;
    for (std::size_t k = 0; k < 4; ++k) {
      EXPECT_GE(both[k], 3U) << "seed " << seed << ", square " << k;
      EXPECT_LT(both[k], 16U) << "seed " << seed << ", square " << k;
      EXPECT_GE(loops_occupied[k].size(), 5U) << "seed " << seed << ", square " << k;
      EXPECT_GE(loops_free[k].size(), 5U) << "seed " << seed << ", square " << k;
    }
  }
}

// A short version of the scenario (5 of its 20 loops) keeps the tests quick.
ScenarioConfig shortScenario() {
  ScenarioConfig scenario = scenarioConfig("mrf_squares");
  scenario.steps = 5 * 24;
  return scenario;
}

// The same scores (NaN matching NaN: parameters not scored).
void expectSameRmse(const TransitionRmse& a, const TransitionRmse& b) {
  const auto same = [](double x, double y) { return x == y || (std::isnan(x) && std::isnan(y)); };
  EXPECT_EQ(a.cells, b.cells);
  EXPECT_TRUE(same(a.p_occ_given_free, b.p_occ_given_free)) << a.p_occ_given_free << " vs " << b.p_occ_given_free;
  EXPECT_TRUE(same(a.p_free_given_occ, b.p_free_given_occ)) << a.p_free_given_occ << " vs " << b.p_free_given_occ;
}

void expectSameOnline(const MrfOnlineOutcome& a, const MrfOnlineOutcome& b) {
  expectSameRmse(a.rmse.sparse, b.rmse.sparse);
  expectSameRmse(a.rmse.well_observed, b.rmse.well_observed);
  for (std::size_t k = 0; k < kCellKinds; ++k) {
    expectSameRmse(a.rmse_by_kind[k].sparse, b.rmse_by_kind[k].sparse);
    expectSameRmse(a.rmse_by_kind[k].well_observed, b.rmse_by_kind[k].well_observed);
  }
  ASSERT_EQ(a.kinds.size(), b.kinds.size());
  for (std::size_t k = 0; k < a.kinds.size(); ++k) {
    EXPECT_EQ(a.kinds[k].transitions.p_occ_given_free, b.kinds[k].transitions.p_occ_given_free);
    EXPECT_EQ(a.kinds[k].transitions.p_free_given_occ, b.kinds[k].transitions.p_free_given_occ);
    EXPECT_EQ(a.kinds[k].weight, b.kinds[k].weight);
  }
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
      expectSameRmse(x, y);
    }
  }
  EXPECT_EQ(a.em_iterations, b.em_iterations);
  EXPECT_EQ(a.objective, b.objective);
  EXPECT_EQ(a.newton_iterations, b.newton_iterations);
}

// Bitwise equal, NaN matching NaN (cells never observed).
bool sameMap(const std::vector<core::TransitionParams>& a, const std::vector<core::TransitionParams>& b) {
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
    EXPECT_EQ(one.repetitions[r].square_cells_both_states, two.repetitions[r].square_cells_both_states);
    expectSameOutcome(one.repetitions[r].plain, two.repetitions[r].plain);
    expectSameOutcome(one.repetitions[r].mrf, two.repetitions[r].mrf);
    expectSameOnline(one.repetitions[r].online, two.repetitions[r].online);
    expectSameOnline(one.repetitions[r].online_kinds, two.repetitions[r].online_kinds);
  }
  // Two repetitions are two different runs.
  EXPECT_NE(one.repetitions[0].run_seed, one.repetitions[1].run_seed);
  EXPECT_NE(one.repetitions[0].mrf.objective, one.repetitions[1].mrf.objective);
  EXPECT_EQ(one.first_maps.observed_steps, two.first_maps.observed_steps);
  EXPECT_TRUE(sameMap(one.first_maps.plain, two.first_maps.plain));
  EXPECT_TRUE(sameMap(one.first_maps.mrf, two.first_maps.mrf));
  EXPECT_TRUE(sameMap(one.first_maps.online, two.first_maps.online));
  EXPECT_TRUE(sameMap(one.first_maps.online_kinds, two.first_maps.online_kinds));
  // Another seed, another experiment.
  config.seed = 2;
  const MrfExperimentResult other = runMrfExperiment(shortScenario(), config);
  EXPECT_NE(other.repetitions[0].run_seed, one.repetitions[0].run_seed);
}

// The sum over 8-neighbour pairs of observed cells of the squared difference of the logits of
// one parameter: what the MRF prior penalises.
double roughness(const MrfMaps& maps, const std::vector<core::TransitionParams>& map, bool occ_given_free) {
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
    for (const core::TransitionParams& p : {maps.plain[i], maps.mrf[i]}) {
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

// The online learners map the same scans: the same cells as offline EM, scored the same way.
// Each cell's own online EM ("online"): cells below min_observed_steps use the prior,
// prior_transitions. Kinds of cells ("online_kinds", the package's default):
// its kinds are learned from the map, and a cell publishes its kind posterior's summary
// from its first observed step on.
TEST(MrfExperiment, OnlineLearnersAreScored) {
  MrfExperimentConfig config;
  config.repetitions = 1;
  const ScenarioConfig scenario = shortScenario();
  const MrfExperimentResult result = runMrfExperiment(scenario, config);
  const MrfRepetition& run = result.repetitions.front();
  const core::MapperConfig defaults = evaluationMapperConfig(scenario);
  ASSERT_EQ(config.sparse_below, defaults.online_em.min_observed_steps);  // sparse = on the prior (cell EM)
  for (const MrfOnlineOutcome* online : {&run.online, &run.online_kinds}) {
    EXPECT_EQ(online->rmse.sparse.cells, run.plain.rmse.sparse.cells);
    EXPECT_EQ(online->rmse.well_observed.cells, run.plain.rmse.well_observed.cells);
    EXPECT_GT(online->seconds, 0.0);
    for (std::size_t k = 0; k < kCellKinds; ++k) {
      const auto kind = static_cast<CellKind>(k);
      for (const auto& [e, plain] : {std::make_pair(online->rmse_by_kind[k].sparse, run.plain.rmse_by_kind[k].sparse),
                                     std::make_pair(online->rmse_by_kind[k].well_observed,
                                                    run.plain.rmse_by_kind[k].well_observed)}) {
        EXPECT_EQ(e.cells, plain.cells) << cellKindName(kind);
        EXPECT_EQ(std::isnan(e.p_occ_given_free), !isScored(kind, true)) << cellKindName(kind);
        EXPECT_EQ(std::isnan(e.p_free_given_occ), !isScored(kind, false)) << cellKindName(kind);
        if (e.cells > 0 && kind == CellKind::kChanging) {
          EXPECT_GT(e.p_occ_given_free, 0.0);
          EXPECT_GT(e.p_free_given_occ, 0.0);
        }
      }
    }
  }
  // The changing cells by what their data show partition the changing kind, for all four.
  const auto changing_kind = static_cast<std::size_t>(CellKind::kChanging);
  for (const auto* by_data : {&run.plain.rmse_changing_by_data, &run.mrf.rmse_changing_by_data,
                              &run.online.rmse_changing_by_data, &run.online_kinds.rmse_changing_by_data}) {
    EXPECT_EQ((*by_data)[0].sparse.cells + (*by_data)[1].sparse.cells,
              run.plain.rmse_by_kind[changing_kind].sparse.cells);
    EXPECT_EQ((*by_data)[0].well_observed.cells + (*by_data)[1].well_observed.cells,
              run.plain.rmse_by_kind[changing_kind].well_observed.cells);
    EXPECT_GT((*by_data)[0].sparse.cells + (*by_data)[0].well_observed.cells, 0U);  // the faces
  }

  // Cell EM: every sparse cell keeps prior_transitions (0.01 / 0.01 as float): a static free
  // cell's error is exactly that.
  const auto free_kind = static_cast<std::size_t>(CellKind::kStaticFree);
  ASSERT_GT(run.online.rmse_by_kind[free_kind].sparse.cells, 0U);
  EXPECT_NEAR(run.online.rmse_by_kind[free_kind].sparse.p_occ_given_free, defaults.prior_transitions.p_occ_given_free,
              1e-8);
  EXPECT_TRUE(run.online.kinds.empty());

  // Kinds of cells: the kinds learned from the map, shares summing to 1,
  // rates within the learner's bounds and moved from where they started; the biggest kind is
  // the free floor, so a sparse free cell, which the floor explains, is far closer to its
  // truth than on the fixed prior.
  ASSERT_EQ(run.online_kinds.kinds.size(), static_cast<std::size_t>(core::kKindCount));
  const core::KindsConfig kinds_config;
  double shares = 0.0;
  std::size_t moved = 0;
  std::size_t biggest = 0;
  for (std::size_t k = 0; k < run.online_kinds.kinds.size(); ++k) {
    const MrfLearnedKind& kind = run.online_kinds.kinds[k];
    shares += kind.weight;
    EXPECT_GT(kind.weight, 0.0) << k;
    for (const double p : {kind.transitions.p_occ_given_free, kind.transitions.p_free_given_occ}) {
      EXPECT_GE(p, defaults.online_em.p_min * (1.0 - 1e-9)) << k;
      EXPECT_LE(p, defaults.online_em.p_max * (1.0 + 1e-9)) << k;
    }
    moved += kind.transitions.p_occ_given_free != kinds_config.initial_transitions[k].p_occ_given_free ||
             kind.transitions.p_free_given_occ != kinds_config.initial_transitions[k].p_free_given_occ;
    if (kind.weight > run.online_kinds.kinds[biggest].weight) biggest = k;
  }
  EXPECT_NEAR(shares, 1.0, 1e-6);
  EXPECT_GT(moved, 0U);
  EXPECT_GT(run.online_kinds.kinds[biggest].weight, 0.5);
  EXPECT_LT(run.online_kinds.kinds[biggest].transitions.p_occ_given_free,
            0.1 * defaults.prior_transitions.p_occ_given_free);
  EXPECT_LT(run.online_kinds.rmse_by_kind[free_kind].sparse.p_occ_given_free,
            0.5 * run.online.rmse_by_kind[free_kind].sparse.p_occ_given_free);

  // The maps: learned values exactly where offline EM has them, within the learners' bounds;
  // the two learners are two learners.
  const MrfMaps& maps = result.first_maps;
  ASSERT_EQ(maps.online.size(), maps.plain.size());
  ASSERT_EQ(maps.online_kinds.size(), maps.plain.size());
  std::size_t kinds_differs = 0;
  for (std::size_t i = 0; i < maps.plain.size(); ++i) {
    for (const core::TransitionParams& p : {maps.online[i], maps.online_kinds[i]}) {
      EXPECT_EQ(std::isnan(p.p_occ_given_free), maps.observed_steps[i] == 0) << i;
      EXPECT_EQ(std::isnan(p.p_free_given_occ), maps.observed_steps[i] == 0) << i;
      if (maps.observed_steps[i] == 0) continue;
      EXPECT_GE(p.p_occ_given_free, defaults.online_em.p_min * (1.0 - 1e-6));
      EXPECT_LE(p.p_free_given_occ, defaults.online_em.p_max * (1.0 + 1e-6));
    }
    if (maps.observed_steps[i] == 0) continue;
    kinds_differs += maps.online[i].p_occ_given_free != maps.online_kinds[i].p_occ_given_free;
  }
  EXPECT_GT(kinds_differs, run.cells_observed / 2);
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
}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
