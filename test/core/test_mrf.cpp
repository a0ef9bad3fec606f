// The MRF-smoothed M-step (mrf.h) and offline EM with it (offline_em.h, mrf_temperature).
#include "dynamic_occupancy_grid/core/cell/mrf.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>

#include "dynamic_occupancy_grid/core/cell/offline_em.h"

namespace dog = dynamic_occupancy_grid::core;

namespace {

double logit(double p) { return std::log(p / (1.0 - p)); }
double sigmoid(double x) { return 1.0 / (1.0 + std::exp(-x)); }

// Cells of a w x h block with some holes, and random counts.
struct RandomProblem {
  std::vector<dog::CellXY> cells;
  dog::CellNeighbours graph;
  dog::MrfMapProblem problem;
};

RandomProblem randomProblem(unsigned seed, double inverse_temperature, int w = 7, int h = 5) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  RandomProblem p;
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      if (unit(rng) < 0.15) continue;  // holes: cells with fewer neighbours
      p.cells.push_back(dog::CellXY{x, y});
    }
  }
  p.graph = dog::eightNeighbours(p.cells);
  p.problem.graph = &p.graph;
  p.problem.inverse_temperature = inverse_temperature;
  p.problem.lo = logit(0.5);
  p.problem.hi = logit(1.0 - 1e-4);
  for (std::size_t i = 0; i < p.cells.size(); ++i) {
    // Some cells with hardly any evidence, some with a lot.
    const double scale = unit(rng) < 0.3 ? 0.5 : 200.0;
    p.problem.stay.push_back(scale * unit(rng));
    p.problem.leave.push_back(scale * 0.3 * unit(rng));
  }
  return p;
}

TEST(EightNeighbours, FindsTheNeighboursAmongTheGivenCells) {
  const std::vector<dog::CellXY> cells{{0, 0}, {1, 0}, {1, 1}, {3, 3}, {-1, -1}};
  const dog::CellNeighbours graph = dog::eightNeighbours(cells);
  const auto neighbours = [&](std::size_t i) {
    return std::vector<std::uint32_t>(graph.indices.begin() + graph.offsets[i], graph.indices.begin() + graph.offsets[i + 1]);
  };
  EXPECT_EQ(neighbours(0), (std::vector<std::uint32_t>{1, 2, 4}));
  EXPECT_EQ(neighbours(1), (std::vector<std::uint32_t>{0, 2}));
  EXPECT_EQ(neighbours(2), (std::vector<std::uint32_t>{0, 1}));
  EXPECT_TRUE(neighbours(3).empty());
  EXPECT_EQ(neighbours(4), (std::vector<std::uint32_t>{0}));
  EXPECT_EQ(graph.pairs(), 4U);
  EXPECT_THROW(dog::eightNeighbours({{2, 2}, {2, 2}}), std::invalid_argument);
}

TEST(MrfMapObjective, GradientMatchesFiniteDifferences) {
  for (unsigned seed = 1; seed <= 5; ++seed) {
    const RandomProblem p = randomProblem(seed, 1.0 / 50.0);
    std::mt19937 rng(seed + 100);
    std::uniform_real_distribution<double> value(-3.0, 6.0);
    std::vector<double> l(p.cells.size());
    for (double& v : l) v = value(rng);
    const std::vector<double> gradient = dog::mrfMapGradient(p.problem, l);
    for (std::size_t i = 0; i < l.size(); ++i) {
      const double step = 1e-5;
      std::vector<double> up = l;
      std::vector<double> down = l;
      up[i] += step;
      down[i] -= step;
      const double numeric = (dog::mrfMapObjective(p.problem, up) - dog::mrfMapObjective(p.problem, down)) / (2 * step);
      ASSERT_NEAR(gradient[i], numeric, 1e-6 * std::max(1.0, std::abs(numeric))) << "seed " << seed << " cell " << i;
    }
  }
}

TEST(MrfMapObjective, PriorIsTheSumOverPairs) {
  const std::vector<dog::CellXY> cells{{0, 0}, {1, 0}, {2, 0}};  // (0,0)-(2,0) are not neighbours
  const dog::CellNeighbours graph = dog::eightNeighbours(cells);
  EXPECT_DOUBLE_EQ(dog::mrfPrior(graph, 0.5, {1.0, 2.0, 4.0}), -0.5 * (1.0 + 4.0));
}

// KKT conditions of the box-constrained concave problem at the solution, and no better
// point nearby.
TEST(MaximizeMrfMap, ReachesTheConstrainedMaximum) {
  for (unsigned seed = 1; seed <= 5; ++seed) {
    const RandomProblem p = randomProblem(seed, 1.0 / 50.0, 12, 9);
    std::vector<double> l(p.cells.size(), 0.0);
    const int iterations = dog::maximizeMrfMap(p.problem, l);
    EXPECT_GT(iterations, 0);
    EXPECT_LT(iterations, 100);
    const std::vector<double> gradient = dog::mrfMapGradient(p.problem, l);
    for (std::size_t i = 0; i < l.size(); ++i) {
      ASSERT_GE(l[i], p.problem.lo);
      ASSERT_LE(l[i], p.problem.hi);
      if (l[i] > p.problem.lo && l[i] < p.problem.hi) {
        ASSERT_NEAR(gradient[i], 0.0, 1e-6) << "seed " << seed << " cell " << i;
      } else if (l[i] == p.problem.lo) {
        ASSERT_LE(gradient[i], 1e-6);
      } else {
        ASSERT_GE(gradient[i], -1e-6);
      }
    }
    const double best = dog::mrfMapObjective(p.problem, l);
    std::mt19937 rng(seed);
    std::normal_distribution<double> jitter(0.0, 0.05);
    for (int k = 0; k < 50; ++k) {
      std::vector<double> other = l;
      for (double& v : other) v = std::clamp(v + jitter(rng), p.problem.lo, p.problem.hi);
      EXPECT_LE(dog::mrfMapObjective(p.problem, other), best + 1e-9);
    }
  }
}

// A start just inside the upper bound, where the full projected Newton step predicts no
// gain but a shorter one does: the line search must keep halving, not give up.
TEST(MaximizeMrfMap, KeepsSearchingWhenTheClippedStepPredictsNothing) {
  const std::vector<dog::CellXY> cells{{0, 0}, {1, 0}};
  const dog::CellNeighbours graph = dog::eightNeighbours(cells);
  dog::MrfMapProblem problem;
  problem.graph = &graph;
  problem.inverse_temperature = 57.887275017243994;
  problem.lo = -3.0;
  problem.hi = 3.0;
  problem.stay = {697.28578000763468, 40.335874917086755};
  problem.leave = {0.048198958893809957, 19.974258220561108};
  std::vector<double> l{2.9999960041146623, 2.9999706307559975};
  dog::maximizeMrfMap(problem, l);
  const std::vector<double> gradient = dog::mrfMapGradient(problem, l);
  // KKT: the first at the upper bound pushing out, the second interior with zero gradient.
  EXPECT_EQ(l[0], 3.0);
  EXPECT_GT(gradient[0], 0.0);
  EXPECT_NEAR(gradient[1], 0.0, 1e-6);
  EXPECT_LT(l[1], 2.9);
}

// With a near-infinite coupling every cell takes one common value, the one that maximises
// the summed evidence (a shift of all logits costs no smoothing: the solver must still move).
TEST(MaximizeMrfMap, StrongCouplingGivesOneCommonValue) {
  const RandomProblem p = randomProblem(4, 1e6);
  std::vector<double> l(p.cells.size(), 0.5);
  dog::maximizeMrfMap(p.problem, l);
  double stay = 0.0;
  double leave = 0.0;
  for (std::size_t i = 0; i < l.size(); ++i) {
    stay += p.problem.stay[i];
    leave += p.problem.leave[i];
  }
  // Only if the graph is connected; the random block with 15 % holes almost always is, and
  // this seed is.
  const double common = std::clamp(logit(stay / (stay + leave)), p.problem.lo, p.problem.hi);
  for (const double v : l) EXPECT_NEAR(v, common, 1e-3);
}

// Newton with the right Hessian converges in a handful of steps; a wrong curvature (say the
// coupling's factor 2 forgotten) makes it linear and slow.
TEST(MaximizeMrfMap, ConvergesInFewNewtonSteps) {
  for (unsigned seed = 1; seed <= 5; ++seed) {
    RandomProblem p = randomProblem(seed, 1.0 / 5.0, 12, 9);
    p.problem.lo = -20.0;
    p.problem.hi = 20.0;
    std::vector<double> l(p.cells.size(), 0.0);
    EXPECT_LE(dog::maximizeMrfMap(p.problem, l), 15) << seed;
  }
}

TEST(MrfMapObjectiveChange, EqualsTheDifferenceOfObjectives) {
  const RandomProblem p = randomProblem(2, 0.3);
  std::vector<double> a(p.cells.size(), 0.4);
  std::vector<double> b = a;
  for (std::size_t i = 0; i < b.size(); i += 3) b[i] += 0.25 * static_cast<double>(i % 5);
  EXPECT_NEAR(dog::mrfMapObjectiveChange(p.problem, a, b),
              dog::mrfMapObjective(p.problem, b) - dog::mrfMapObjective(p.problem, a), 1e-8);
}

TEST(MaximizeMrfMap, WithoutCouplingEachCellIsItsRatio) {
  const RandomProblem p = randomProblem(3, 0.0);
  std::vector<double> l(p.cells.size(), 1.0);
  dog::maximizeMrfMap(p.problem, l);
  for (std::size_t i = 0; i < l.size(); ++i) {
    const double stay = p.problem.stay[i];
    const double leave = p.problem.leave[i];
    const double expected = std::clamp(logit(stay / (stay + leave)), p.problem.lo, p.problem.hi);
    ASSERT_NEAR(l[i], expected, 1e-7) << i;
  }
}

TEST(MaximizeMrfMap, ACellWithoutEvidenceTakesItsNeighboursMean) {
  const std::vector<dog::CellXY> cells{{0, 0}, {1, 0}, {2, 0}};
  const dog::CellNeighbours graph = dog::eightNeighbours(cells);
  dog::MrfMapProblem problem;
  problem.graph = &graph;
  problem.inverse_temperature = 1.0 / 50.0;
  problem.stay = {900.0, 0.0, 500.0};
  problem.leave = {100.0, 0.0, 500.0};
  problem.lo = -20.0;
  problem.hi = 20.0;
  std::vector<double> l(3, 0.0);
  dog::maximizeMrfMap(problem, l);
  EXPECT_NEAR(l[1], 0.5 * (l[0] + l[2]), 1e-8);
  // The ends barely move off their own evidence (1000 counts against a weak coupling).
  EXPECT_NEAR(sigmoid(l[0]), 0.9, 0.01);
  EXPECT_NEAR(sigmoid(l[2]), 0.5, 0.01);
}

// With a gain tolerance Newton takes the step that predicts at most that gain and stops: the
// same path as without, cut short. Checked against the exact solver's iterates: the result
// is its iterate after as many steps (a solver stopping before that step differs), within the
// tolerance of the maximum, and two steps earlier it was still more than the tolerance away
// (a gain measured too large, or the tolerance ignored, stops elsewhere).
TEST(MaximizeMrfMap, GainToleranceStopsWhereTheStepGainsLittle) {
  const auto iterate = [](const dog::MrfMapProblem& problem, int newton_steps) {
    std::vector<double> l(problem.stay.size(), 0.0);
    dog::maximizeMrfMap(problem, l, newton_steps);
    return l;
  };
  for (unsigned seed = 1; seed <= 5; ++seed) {
    const RandomProblem p = randomProblem(seed, 1.0 / 50.0, 12, 9);
    std::vector<double> exact(p.cells.size(), 0.0);
    const int exact_iterations = dog::maximizeMrfMap(p.problem, exact);
    const double best = dog::mrfMapObjective(p.problem, exact);
    for (const double tolerance : {1e-2, 1.0}) {
      std::vector<double> early(p.cells.size(), 0.0);
      const int iterations = dog::maximizeMrfMap(p.problem, early, 100, tolerance);
      EXPECT_LT(iterations, exact_iterations) << "seed " << seed << " tolerance " << tolerance;
      ASSERT_GE(iterations, 1);
      EXPECT_EQ(early, iterate(p.problem, iterations)) << "seed " << seed << " tolerance " << tolerance;
      const double gap = best - dog::mrfMapObjective(p.problem, early);
      EXPECT_GE(gap, -1e-9);
      EXPECT_LE(gap, tolerance) << "seed " << seed;
      if (iterations >= 2) {
        EXPECT_GT(best - dog::mrfMapObjective(p.problem, iterate(p.problem, iterations - 2)), tolerance)
            << "seed " << seed << " tolerance " << tolerance;
      }
    }
  }
}

TEST(MaximizeMrfMap, RejectsBadInput) {
  const RandomProblem p = randomProblem(1, 0.1);
  std::vector<double> wrong_size(2, 0.0);
  EXPECT_THROW(dog::maximizeMrfMap(p.problem, wrong_size), std::invalid_argument);
  dog::MrfMapProblem negative = p.problem;
  negative.stay[0] = -1.0;
  std::vector<double> l(p.cells.size(), 0.0);
  EXPECT_THROW(dog::maximizeMrfMap(negative, l), std::invalid_argument);
  dog::MrfMapProblem unbounded = p.problem;
  unbounded.hi = std::numeric_limits<double>::infinity();
  EXPECT_THROW(dog::maximizeMrfMap(unbounded, l), std::invalid_argument);
  EXPECT_THROW(dog::maximizeMrfMap(p.problem, l, 100, -1e-3), std::invalid_argument);
  EXPECT_THROW(dog::maximizeMrfMap(p.problem, l, 100, std::numeric_limits<double>::infinity()), std::invalid_argument);
  EXPECT_THROW(dog::maximizeMrfMap(p.problem, l, 100, std::numeric_limits<double>::quiet_NaN()), std::invalid_argument);
}

// ---- offline EM with the MRF ----------------------------------------------------------

// Cells of a 10 x 10 block observed from a hidden chain each: the left half changing with
// p = 0.2, the right half with 0.02; one cell in each half observed only 4 times.
dog::ObservationSequences blockSequences(unsigned seed, int steps = 400) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  dog::SequenceBuilder builder;
  for (int y = 0; y < 10; ++y) {
    for (int x = 0; x < 10; ++x) {
      const double p = x < 5 ? 0.2 : 0.02;
      const bool sparse = (x == 2 || x == 7) && y == 5;
      bool occupied = unit(rng) < 0.5;
      int observed = 0;
      for (int t = 0; t < steps; ++t) {
        if (unit(rng) < p) occupied = !occupied;
        if (sparse ? (observed < 4 && t % 50 == 0) : unit(rng) < 0.5) {
          const bool hit = unit(rng) < (occupied ? 0.9 : 0.1);
          builder.add(x, y, t, hit ? 1 : 0, hit ? 0 : 1);
          ++observed;
        }
      }
    }
  }
  return builder.build();
}

dog::OfflineEmConfig emConfig() {
  dog::OfflineEmConfig config;
  config.prior_weight = 2.0;
  config.max_iterations = 15;
  config.tolerance = 0.0;
  return config;
}

TEST(OfflineEmMrf, InfiniteTemperatureIsPlainEm) {
  const dog::ObservationSequences sequences = blockSequences(1);
  const dog::ObservationModel sensor(0.9, 0.1);
  // Five EM iterations: on the flat likelihood of the sparse cells EM itself amplifies
  // differences at the solver's precision over many iterations.
  dog::OfflineEmConfig config = emConfig();
  config.max_iterations = 5;
  const dog::OfflineEmResult plain = dog::runOfflineEm(sequences, sensor, config);
  config.mrf_temperature = 1e300;
  const dog::OfflineEmResult mrf = dog::runOfflineEm(sequences, sensor, config);
  ASSERT_EQ(mrf.params.size(), plain.params.size());
  // Equal to the Newton solver's precision (1e-10 in logits per M-step).
  for (std::size_t c = 0; c < plain.params.size(); ++c) {
    ASSERT_NEAR(mrf.params[c].p_occ_given_free, plain.params[c].p_occ_given_free, 1e-9) << c;
    ASSERT_NEAR(mrf.params[c].p_free_given_occ, plain.params[c].p_free_given_occ, 1e-9) << c;
    ASSERT_NEAR(mrf.final_p_occ[c], plain.final_p_occ[c], 1e-8) << c;
  }
  ASSERT_EQ(mrf.objective.size(), plain.objective.size());
  for (std::size_t k = 0; k < plain.objective.size(); ++k) {
    EXPECT_NEAR(mrf.objective[k], plain.objective[k], 1e-8 * std::abs(plain.objective[k]));
  }
  EXPECT_EQ(mrf.mrf_newton_iterations.size(), 5U);
  EXPECT_TRUE(plain.mrf_newton_iterations.empty());
}

TEST(OfflineEmMrf, ObjectiveNeverDecreasesAndThreadsDoNotMatter) {
  const dog::ObservationSequences sequences = blockSequences(2);
  const dog::ObservationModel sensor(0.9, 0.1);
  dog::OfflineEmConfig config = emConfig();
  config.mrf_temperature = 50.0;
  config.threads = 1;
  const dog::OfflineEmResult one = dog::runOfflineEm(sequences, sensor, config);
  config.threads = 2;
  const dog::OfflineEmResult two = dog::runOfflineEm(sequences, sensor, config);
  for (std::size_t k = 1; k < one.objective.size(); ++k) {
    EXPECT_GE(one.objective[k], one.objective[k - 1] - 1e-9 * std::abs(one.objective[k - 1])) << k;
  }
  // The reported objective is the log-likelihood plus the MAP prior plus the MRF prior of the
  // returned parameters, recomputed here independently.
  double log_likelihood = 0.0;
  double log_prior = 0.0;
  std::vector<double> logit_occ(sequences.cellCount());
  std::vector<double> logit_free(sequences.cellCount());
  std::vector<dog::CellXY> cells(sequences.cellCount());
  for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
    const dog::TransitionParams& a = one.params[c];
    log_likelihood += dog::forwardBackward(sequences.begin(c), sequences.end(c), sensor, a, 0.5).log_likelihood;
    const double w = config.prior_weight;
    log_prior += w * (1.0 - config.prior.p_free_given_occ) * std::log(1.0 - a.p_free_given_occ) +
                 w * config.prior.p_free_given_occ * std::log(a.p_free_given_occ) +
                 w * config.prior.p_occ_given_free * std::log(a.p_occ_given_free) +
                 w * (1.0 - config.prior.p_occ_given_free) * std::log(1.0 - a.p_occ_given_free);
    logit_occ[c] = logit(1.0 - a.p_free_given_occ);
    logit_free[c] = logit(1.0 - a.p_occ_given_free);
    cells[c] = sequences.cell(c);
  }
  const dog::CellNeighbours graph = dog::eightNeighbours(cells);
  const double expected = log_likelihood + log_prior + dog::mrfPrior(graph, 1.0 / 50.0, logit_occ) +
                          dog::mrfPrior(graph, 1.0 / 50.0, logit_free);
  EXPECT_NEAR(one.objective.back(), expected, 1e-6 * std::abs(expected));
  for (std::size_t c = 0; c < one.params.size(); ++c) {
    ASSERT_EQ(one.params[c].p_occ_given_free, two.params[c].p_occ_given_free);
    ASSERT_EQ(one.params[c].p_free_given_occ, two.params[c].p_free_given_occ);
  }
  EXPECT_EQ(one.objective, two.objective);
  for (const auto& newton : one.mrf_newton_iterations) {
    EXPECT_GE(newton[0], 0);
    EXPECT_LT(newton[0], 100);
  }
}

// A cell seen 4 times learns little on its own; with the MRF it borrows its neighbours'
// rates. Its likelihood is flat, so EM needs many iterations to let the prior act.
TEST(OfflineEmMrf, SparselyObservedCellsBorrowFromTheirNeighbours) {
  const dog::ObservationModel sensor(0.9, 0.1);
  double plain_error = 0.0;
  double mrf_error = 0.0;
  for (unsigned seed = 1; seed <= 4; ++seed) {
    const dog::ObservationSequences sequences = blockSequences(seed);
    dog::OfflineEmConfig config = emConfig();
    config.max_iterations = 300;
    const dog::OfflineEmResult plain = dog::runOfflineEm(sequences, sensor, config);
    config.mrf_temperature = 50.0;
    const dog::OfflineEmResult mrf = dog::runOfflineEm(sequences, sensor, config);
    for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
      const dog::CellXY cell = sequences.cell(c);
      if (!((cell.x == 2 || cell.x == 7) && cell.y == 5)) continue;
      const double truth = cell.x < 5 ? 0.2 : 0.02;
      plain_error += std::abs(plain.params[c].p_occ_given_free - truth) + std::abs(plain.params[c].p_free_given_occ - truth);
      mrf_error += std::abs(mrf.params[c].p_occ_given_free - truth) + std::abs(mrf.params[c].p_free_given_occ - truth);
    }
  }
  // The target for sparse cells: at least 30 % lower error.
  EXPECT_LT(mrf_error, 0.7 * plain_error) << "plain " << plain_error << ", MRF " << mrf_error;
}

TEST(OfflineEmMrf, ConfigErrors) {
  dog::OfflineEmConfig config;
  config.mrf_temperature = -1.0;
  EXPECT_THROW(config.validate(), std::invalid_argument);
  config.mrf_temperature = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(config.validate(), std::invalid_argument);
  config.mrf_temperature = 1e-10;  // a coupling that swamps any evidence by 1e10
  EXPECT_THROW(config.validate(), std::invalid_argument);
  config.mrf_temperature = 50.0;
  config.symmetric = true;
  EXPECT_THROW(config.validate(), std::invalid_argument);
  config.symmetric = false;
  EXPECT_NO_THROW(config.validate());
}

}  // namespace
