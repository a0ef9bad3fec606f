// Tests of the per-cell HMM of THEORY.md §1-3 (core/cell/cell_model.h).
//
// Every reference value below is computed independently of the code under test: either
// by hand (the arithmetic is written in a comment) or by plain 2-vector / 2x2-matrix
// arithmetic on q = [p(occ), p(free)] and
//   A = [ 1 - p_fo   p_fo     ]
//       [ p_of       1 - p_of ]
// (index 0 = occ, 1 = free), mostly in long double. No reference calls predictOneStep,
// predictOccupancy, bayesUpdate, filterStep or mixingTime.

#include "dynamic_occupancy_grid/core/cell/cell_model.h"

#include <gtest/gtest.h>

#include <cmath>
#include <algorithm>
#include <cstdint>
#include <limits>
#include <optional>
#include <random>
#include <stdexcept>
#include <vector>

namespace dog = dynamic_occupancy_grid::core;

namespace {

using LD = long double;

constexpr double kInf = std::numeric_limits<double>::infinity();

dog::TransitionParams params(double p_of, double p_fo) {
  dog::TransitionParams t;
  t.p_occ_given_free = p_of;
  t.p_free_given_occ = p_fo;
  return t;
}

// ---- independent reference arithmetic ------------------------------------------------

struct Vec2 {
  LD occ;
  LD free;
};

// Row vector times A: [q0 q1] * [[1-p_fo, p_fo], [p_of, 1-p_of]].
Vec2 timesA(const Vec2& q, LD p_of, LD p_fo) {
  return Vec2{q.occ * (1.0L - p_fo) + q.free * p_of, q.occ * p_fo + q.free * (1.0L - p_of)};
}

// q_t = eta * (q_{t-1} A) o b(z), with b(z) = [p(z|occ), p(z|free)] of h hits, m misses.
LD referenceFilter(LD p_prev, LD p_of, LD p_fo, LD p_hit_occ, LD p_hit_free, int hits,
                   int misses) {
  Vec2 q = timesA(Vec2{p_prev, 1.0L - p_prev}, p_of, p_fo);
  LD b_occ = 1.0L;
  LD b_free = 1.0L;
  for (int i = 0; i < hits; ++i) {
    b_occ *= p_hit_occ;
    b_free *= p_hit_free;
  }
  for (int i = 0; i < misses; ++i) {
    b_occ *= 1.0L - p_hit_occ;
    b_free *= 1.0L - p_hit_free;
  }
  const LD occ = q.occ * b_occ;
  const LD free = q.free * b_free;
  return occ / (occ + free);
}

LD logit(LD p) { return std::log(p / (1.0L - p)); }

// Brute-force mixing time: iterate q <- q A, return the first k >= 0 with
// |q_k(occ) - pi| <= eps, or nullopt if not reached within max_steps.
std::optional<std::int64_t> bruteMixingTime(double p_occ, double p_of, double p_fo, double eps,
                                            std::int64_t max_steps) {
  const LD pi = static_cast<LD>(p_of) / (static_cast<LD>(p_of) + static_cast<LD>(p_fo));
  Vec2 q{p_occ, 1.0L - static_cast<LD>(p_occ)};
  for (std::int64_t k = 0; k <= max_steps; ++k) {
    if (std::fabs(q.occ - pi) <= static_cast<LD>(eps)) return k;
    q = timesA(q, p_of, p_fo);
  }
  return std::nullopt;
}

// Delta_k = |lambda|^k * Delta_0 in long double (for checks where brute force is too long).
LD closedFormDelta(double p_occ, double p_of, double p_fo, LD k) {
  const LD sum = static_cast<LD>(p_of) + static_cast<LD>(p_fo);
  const LD pi = static_cast<LD>(p_of) / sum;
  const LD delta0 = std::fabs(static_cast<LD>(p_occ) - pi);
  const LD log_abs_lambda = sum <= 1.0L ? std::log1p(-sum) : std::log1p(sum - 2.0L);
  return delta0 * std::exp(k * log_abs_lambda);
}

// Hand-computation sensor and cell of the brief.
constexpr double kPHitOcc = 0.7;
constexpr double kPHitFree = 0.2;
constexpr double kPOf = 0.1;
constexpr double kPFo = 0.2;

}  // namespace

// =====================================================================================
// 1. Filter step / Bayes update against hand-computed values.
// =====================================================================================

// Common prediction: q_{t-1} = [0.5, 0.5]
//   q A = [0.5*(1-0.2) + 0.5*0.1, 0.5*0.2 + 0.5*(1-0.1)] = [0.45, 0.55].
TEST(CellModelHandComputed, FilterStepOneHit) {
  const dog::ObservationModel sensor(kPHitOcc, kPHitFree);
  const auto a = params(kPOf, kPFo);
  // b(hit) = [0.7, 0.2]; [0.45*0.7, 0.55*0.2] = [0.315, 0.11]; p = 0.315/0.425 = 63/85.
  const double expected = 63.0 / 85.0;  // 0.741176470588235...
  EXPECT_NEAR(dog::filterStep(0.5, a, sensor.logLikelihoodRatio(1, 0)), expected, 1e-12);
  EXPECT_NEAR(dog::filterStep(0.5, a, std::log(0.7 / 0.2)), expected, 1e-12);
  // The update half alone, from the predicted 0.45.
  EXPECT_NEAR(dog::bayesUpdate(0.45, std::log(0.7 / 0.2)), expected, 1e-12);
}

TEST(CellModelHandComputed, FilterStepOneMiss) {
  const dog::ObservationModel sensor(kPHitOcc, kPHitFree);
  const auto a = params(kPOf, kPFo);
  // b(miss) = [0.3, 0.8]; [0.45*0.3, 0.55*0.8] = [0.135, 0.44]; p = 0.135/0.575 = 27/115.
  const double expected = 27.0 / 115.0;  // 0.234782608695652...
  EXPECT_NEAR(dog::filterStep(0.5, a, sensor.logLikelihoodRatio(0, 1)), expected, 1e-12);
  EXPECT_NEAR(dog::filterStep(0.5, a, std::log(0.3 / 0.8)), expected, 1e-12);
  EXPECT_NEAR(dog::bayesUpdate(0.45, std::log(0.3 / 0.8)), expected, 1e-12);
}

TEST(CellModelHandComputed, FilterStepTwoHitsOneMissFused) {
  const dog::ObservationModel sensor(kPHitOcc, kPHitFree);
  const auto a = params(kPOf, kPFo);
  // Likelihoods multiply: b = [0.7*0.7*0.3, 0.2*0.2*0.8] = [0.147, 0.032].
  // [0.45*0.147, 0.55*0.032] = [0.06615, 0.0176]; p = 0.06615/0.08375 = 1323/1675.
  const double expected = 1323.0 / 1675.0;  // 0.789850746268656...
  EXPECT_NEAR(dog::filterStep(0.5, a, sensor.logLikelihoodRatio(2, 1)), expected, 1e-12);
  EXPECT_NEAR(dog::filterStep(0.5, a, std::log(0.147 / 0.032)), expected, 1e-12);
}

TEST(CellModelHandComputed, FilterStepNoEvidenceIsPurePrediction) {
  const dog::ObservationModel sensor(kPHitOcc, kPHitFree);
  const auto a = params(kPOf, kPFo);
  // b = [1, 1]: p = 0.45.
  EXPECT_NEAR(dog::filterStep(0.5, a, sensor.logLikelihoodRatio(0, 0)), 0.45, 1e-12);
  EXPECT_NEAR(dog::filterStep(0.5, a, 0.0), 0.45, 1e-12);
  // From prior 0.9: [0.9*0.8 + 0.1*0.1, ...] = [0.73, 0.27].
  EXPECT_NEAR(dog::filterStep(0.9, a, 0.0), 0.73, 1e-12);
  EXPECT_NEAR(dog::predictOneStep(0.9, a), 0.73, 1e-12);
  EXPECT_NEAR(dog::predictOneStep(0.5, a), 0.45, 1e-12);
}

TEST(CellModelHandComputed, FilterStepOneHitFromOtherPrior) {
  const dog::ObservationModel sensor(kPHitOcc, kPHitFree);
  const auto a = params(kPOf, kPFo);
  // q A = [0.73, 0.27]; [0.73*0.7, 0.27*0.2] = [0.511, 0.054]; p = 0.511/0.565 = 511/565.
  EXPECT_NEAR(dog::filterStep(0.9, a, sensor.logLikelihoodRatio(1, 0)), 511.0 / 565.0, 1e-12);
}

TEST(CellModelHandComputed, FilterStepMatchesMatrixReferenceRandom) {
  std::mt19937_64 rng(20240601);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_int_distribution<int> count(0, 6);
  for (int trial = 0; trial < 3000; ++trial) {
    double p_hit_free = unit(rng) * 0.98 + 0.01;
    double p_hit_occ = unit(rng) * 0.98 + 0.01;
    if (p_hit_occ == p_hit_free) continue;
    if (p_hit_occ < p_hit_free) std::swap(p_hit_occ, p_hit_free);
    const dog::ObservationModel sensor(p_hit_occ, p_hit_free);
    const double p_of = unit(rng);
    const double p_fo = unit(rng);
    const double prior = unit(rng);
    const int h = count(rng);
    const int m = count(rng);
    const LD expected = referenceFilter(prior, p_of, p_fo, p_hit_occ, p_hit_free, h, m);
    const double actual = dog::filterStep(prior, params(p_of, p_fo), sensor.logLikelihoodRatio(
                                                                         static_cast<std::uint32_t>(h),
                                                                         static_cast<std::uint32_t>(m)));
    ASSERT_NEAR(actual, static_cast<double>(expected), 1e-12)
        << "prior=" << prior << " p_of=" << p_of << " p_fo=" << p_fo << " h=" << h
        << " m=" << m << " p_hit_occ=" << p_hit_occ << " p_hit_free=" << p_hit_free;
  }
}

// =====================================================================================
// 2. A = I reproduces the standard log-odds occupancy grid; clamping.
// =====================================================================================

TEST(CellModelStaticGrid, IdentityTransitionEqualsLogOddsUpdate) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_int_distribution<int> count(0, 12);
  const dog::LogOddsClamp no_clamp{-kInf, kInf};
  const auto identity = params(0.0, 0.0);
  for (int trial = 0; trial < 3000; ++trial) {
    double p_hit_free = unit(rng) * 0.9 + 0.05;
    double p_hit_occ = unit(rng) * 0.9 + 0.05;
    if (p_hit_occ == p_hit_free) continue;
    if (p_hit_occ < p_hit_free) std::swap(p_hit_occ, p_hit_free);
    const dog::ObservationModel sensor(p_hit_occ, p_hit_free);
    const double prior = unit(rng) * 0.98 + 0.01;
    const int h = count(rng);
    const int m = count(rng);

    // The textbook formula, written out here.
    const LD expected_logit =
        logit(static_cast<LD>(prior)) +
        h * std::log(static_cast<LD>(p_hit_occ) / static_cast<LD>(p_hit_free)) +
        m * std::log((1.0L - p_hit_occ) / (1.0L - p_hit_free));
    const double llr = sensor.logLikelihoodRatio(static_cast<std::uint32_t>(h),
                                                 static_cast<std::uint32_t>(m));
    const double tol = 1e-12 * (1.0 + std::fabs(static_cast<double>(expected_logit)));
    ASSERT_NEAR(llr, static_cast<double>(expected_logit - logit(static_cast<LD>(prior))), tol);

    const double grid_logit = dog::updateLogOdds(static_cast<double>(logit(prior)), llr, no_clamp);
    ASSERT_NEAR(grid_logit, static_cast<double>(expected_logit), tol);

    const double posterior = dog::filterStep(prior, identity, llr);
    // Same result in probability space ...
    const LD expected_p = 1.0L / (1.0L + std::exp(-expected_logit));
    ASSERT_NEAR(posterior, static_cast<double>(expected_p), 1e-12);
    ASSERT_NEAR(posterior, dog::logOddsToProbability(grid_logit), 1e-12);
    // ... and in log-odds space where the logit of a double is well conditioned.
    if (std::fabs(static_cast<double>(expected_logit)) < 12.0) {
      ASSERT_NEAR(static_cast<double>(logit(static_cast<LD>(posterior))), grid_logit, 1e-9)
          << "prior=" << prior << " h=" << h << " m=" << m;
      ASSERT_NEAR(dog::probabilityToLogOdds(posterior), grid_logit, 1e-9);
    }
  }
}

TEST(CellModelStaticGrid, UpdateLogOddsClamps) {
  const dog::LogOddsClamp clamp{-2.0, 3.5};
  EXPECT_DOUBLE_EQ(dog::updateLogOdds(0.0, 1.0, clamp), 1.0);       // inside: unchanged
  EXPECT_DOUBLE_EQ(dog::updateLogOdds(3.0, 1.0, clamp), 3.5);       // above max
  EXPECT_DOUBLE_EQ(dog::updateLogOdds(-1.5, -1.0, clamp), -2.0);    // below min
  EXPECT_DOUBLE_EQ(dog::updateLogOdds(3.5, -0.5, clamp), 3.0);      // clamped after the step
  EXPECT_DOUBLE_EQ(dog::updateLogOdds(-2.0, 0.75, clamp), -1.25);
  EXPECT_DOUBLE_EQ(dog::updateLogOdds(10.0, 0.0, clamp), 3.5);
  EXPECT_DOUBLE_EQ(dog::updateLogOdds(0.0, 1e300, clamp), 3.5);
  EXPECT_DOUBLE_EQ(dog::updateLogOdds(0.0, -1e300, clamp), -2.0);
  // Defaults are the documented ones.
  const dog::LogOddsClamp defaults;
  EXPECT_DOUBLE_EQ(dog::updateLogOdds(0.0, 100.0, defaults), defaults.max_log_odds);
  EXPECT_DOUBLE_EQ(dog::updateLogOdds(0.0, -100.0, defaults), defaults.min_log_odds);
  // Random: result is the clamp of the sum.
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-10.0, 10.0);
  for (int i = 0; i < 1000; ++i) {
    const double l = u(rng);
    const double d = u(rng);
    double expected = l + d;
    if (expected < -2.0) expected = -2.0;
    if (expected > 3.5) expected = 3.5;
    ASSERT_DOUBLE_EQ(dog::updateLogOdds(l, d, clamp), expected);
  }
}

TEST(CellModelStaticGrid, LogOddsConversions) {
  EXPECT_NEAR(dog::logOddsToProbability(0.0), 0.5, 1e-15);
  EXPECT_NEAR(dog::logOddsToProbability(std::log(3.0)), 0.75, 1e-15);
  EXPECT_NEAR(dog::logOddsToProbability(-std::log(3.0)), 0.25, 1e-15);
  EXPECT_EQ(dog::logOddsToProbability(1000.0), 1.0);
  EXPECT_EQ(dog::logOddsToProbability(-1000.0), 0.0);
  EXPECT_NEAR(dog::probabilityToLogOdds(0.75), std::log(3.0), 1e-15);
  EXPECT_EQ(dog::probabilityToLogOdds(1.0), kInf);
  EXPECT_EQ(dog::probabilityToLogOdds(0.0), -kInf);
}

// =====================================================================================
// 3. Closed-form prediction == iterated q <- q A.
// =====================================================================================

namespace {

void expectPredictionMatchesIteration(double p_occ, double p_of, double p_fo, int max_k) {
  const auto a = params(p_of, p_fo);
  Vec2 q{p_occ, 1.0L - static_cast<LD>(p_occ)};
  for (int k = 0; k <= max_k; ++k) {
    const double actual = dog::predictOccupancy(p_occ, a, k);
    ASSERT_NEAR(actual, static_cast<double>(q.occ), 1e-12)
        << "p_occ=" << p_occ << " p_of=" << p_of << " p_fo=" << p_fo << " k=" << k;
    q = timesA(q, p_of, p_fo);
  }
}

}  // namespace

TEST(CellModelPrediction, ClosedFormMatchesIterationRandom) {
  std::mt19937_64 rng(12345);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_int_distribution<int> kdist(0, 2000);
  int negative_lambda = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    double p_of;
    double p_fo;
    switch (trial % 4) {
      case 0:  // anywhere in [0,1]^2 (half of these have lambda < 0)
        p_of = unit(rng);
        p_fo = unit(rng);
        break;
      case 1:  // slow cells
        p_of = std::pow(10.0, -6.0 * unit(rng));
        p_of *= 1e-2;
        p_fo = 1e-2 * std::pow(10.0, -6.0 * unit(rng));
        break;
      case 2:  // p_of + p_fo > 1: oscillating
        p_of = 0.5 + 0.5 * unit(rng);
        p_fo = 0.5 + 0.5 * unit(rng);
        break;
      default:  // near lambda = -1
        p_of = 1.0 - 1e-3 * unit(rng);
        p_fo = 1.0 - 1e-3 * unit(rng);
        break;
    }
    if (p_of + p_fo > 1.0) ++negative_lambda;
    const double p_occ = unit(rng);
    const int k = kdist(rng);
    Vec2 q{p_occ, 1.0L - static_cast<LD>(p_occ)};
    for (int i = 0; i < k; ++i) q = timesA(q, p_of, p_fo);
    ASSERT_NEAR(dog::predictOccupancy(p_occ, params(p_of, p_fo), k), static_cast<double>(q.occ),
                1e-12)
        << "p_occ=" << p_occ << " p_of=" << p_of << " p_fo=" << p_fo << " k=" << k;
  }
  EXPECT_GT(negative_lambda, 1000);
}

TEST(CellModelPrediction, EdgeCases) {
  // Every k from 0 to 200 for a few handpicked cells.
  expectPredictionMatchesIteration(0.9, 0.1, 0.2, 200);     // generic
  expectPredictionMatchesIteration(0.9, 0.7, 0.8, 200);     // lambda = -0.5
  expectPredictionMatchesIteration(0.2, 0.25, 0.75, 200);   // lambda = 0 (exact)
  expectPredictionMatchesIteration(0.2, 0.5, 0.5, 200);     // lambda = 0 (exact)
  expectPredictionMatchesIteration(0.2, 1.0, 0.0, 200);     // lambda = 0, pi = 1
  expectPredictionMatchesIteration(0.2, 0.0, 1.0, 200);     // lambda = 0, pi = 0
  expectPredictionMatchesIteration(0.2, 1.0, 1.0, 200);     // lambda = -1: flips forever
  expectPredictionMatchesIteration(0.3, 0.0, 0.0, 200);     // static
  expectPredictionMatchesIteration(0.3, 1e-9, 0.0, 200);    // absorbing in occ, slow
  expectPredictionMatchesIteration(0.3, 0.0, 0.3, 200);     // absorbing in free
  expectPredictionMatchesIteration(0.0, 0.4, 0.1, 200);     // certain beliefs
  expectPredictionMatchesIteration(1.0, 0.4, 0.1, 200);

  // lambda = 0 for p_of + p_fo == 1 exactly (p in [0.5, 1] makes 1 - p exact).
  std::mt19937_64 rng(99);
  std::uniform_real_distribution<double> half(0.5, 1.0);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  for (int i = 0; i < 500; ++i) {
    const double p = half(rng);
    const double p_of = (i % 2 == 0) ? p : 1.0 - p;
    const double p_fo = (i % 2 == 0) ? 1.0 - p : p;
    ASSERT_EQ(p_of + p_fo, 1.0);
    const double q = unit(rng);
    EXPECT_EQ(dog::predictOccupancy(q, params(p_of, p_fo), 0), q);
    for (int k = 1; k < 5; ++k) {
      // One step of a rank-one A lands on pi = p_of.
      ASSERT_NEAR(dog::predictOccupancy(q, params(p_of, p_fo), k), p_of, 1e-12);
    }
  }

  // p_of = p_fo = 1: the state flips every step.
  for (int k = 0; k < 10; ++k) {
    const double expected = (k % 2 == 0) ? 0.2 : 0.8;
    EXPECT_NEAR(dog::predictOccupancy(0.2, params(1.0, 1.0), k), expected, 1e-15);
  }
  EXPECT_NEAR(dog::predictOccupancy(0.2, params(1.0, 1.0), 2001), 0.8, 1e-12);
  EXPECT_NEAR(dog::predictOccupancy(0.2, params(1.0, 1.0), 2000), 0.2, 1e-12);

  // Static cells keep the current belief for every k, including huge k.
  for (double q : {0.0, 1e-300, 0.3, 0.5, 0.999, 1.0}) {
    for (std::int64_t k : {std::int64_t{0}, std::int64_t{1}, std::int64_t{1000},
                           std::int64_t{1} << 50}) {
      EXPECT_EQ(dog::predictOccupancy(q, params(0.0, 0.0), k), q);
    }
  }

  // k = 0 returns the belief for every kind of cell.
  for (const auto& c : std::vector<std::pair<double, double>>{
           {0.1, 0.2}, {0.9, 0.8}, {1.0, 1.0}, {0.5, 0.5}, {0.0, 0.0}, {1e-12, 3e-12}}) {
    EXPECT_EQ(dog::predictOccupancy(0.37, params(c.first, c.second), 0), 0.37);
  }

  // Very large k converges to pi (and does not produce NaN).
  const double big = dog::predictOccupancy(0.9, params(0.1, 0.3), std::int64_t{1} << 40);
  EXPECT_NEAR(big, 0.25, 1e-15);
}

// =====================================================================================
// 4. Mixing time == brute force.
// =====================================================================================

namespace {

constexpr std::int64_t kBruteCap = 1000000;

// Checks the implementation against the brute force. A disagreement is only tolerated when
// the exact Delta at the boundary is within relative 1e-9 of epsilon (a rounding tie);
// returns true in that case so the caller can count ties.
bool checkMixingAgainstBrute(double p_occ, double p_of, double p_fo, double eps) {
  const auto actual = dog::mixingTime(p_occ, params(p_of, p_fo), eps);
  const auto brute = bruteMixingTime(p_occ, p_of, p_fo, eps, kBruteCap);
  EXPECT_TRUE(brute.has_value()) << "test parameters exceed the brute-force cap";
  EXPECT_TRUE(actual.has_value()) << "p_occ=" << p_occ << " p_of=" << p_of << " p_fo=" << p_fo
                                  << " eps=" << eps;
  if (!brute || !actual) return false;
  if (*actual == *brute) return false;
  // Tie? Exact Delta at both candidate answers must be within rounding of epsilon.
  const std::int64_t lo = std::min(*actual, *brute);
  const std::int64_t hi = std::max(*actual, *brute);
  const bool tie = (hi - lo == 1) &&
                   std::fabs(closedFormDelta(p_occ, p_of, p_fo, static_cast<LD>(lo)) - eps) <=
                       1e-9L * eps;
  EXPECT_TRUE(tie) << "mixingTime mismatch: p_occ=" << p_occ << " p_of=" << p_of
                   << " p_fo=" << p_fo << " eps=" << eps << " actual=" << *actual
                   << " brute=" << *brute;
  return tie;
}

}  // namespace

TEST(CellModelMixingTime, MatchesBruteForceRandom) {
  std::mt19937_64 rng(4242);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  int checked = 0;
  int ties = 0;
  int nonzero = 0;
  int oscillating = 0;
  std::int64_t max_k = 0;
  for (int trial = 0; trial < 6000; ++trial) {
    double p_of;
    double p_fo;
    switch (trial % 3) {
      case 0:
        p_of = unit(rng);
        p_fo = unit(rng);
        break;
      case 1:  // slow cells, sum in about [2e-5, 2e-1]: answers up to ~1e6 steps
        p_of = 1e-1 * std::pow(10.0, -4.0 * unit(rng));
        p_fo = 1e-1 * std::pow(10.0, -4.0 * unit(rng));
        break;
      default:  // oscillating, some close to lambda = -1
        p_of = 1.0 - 0.5 * std::pow(10.0, -3.0 * unit(rng));
        p_fo = 1.0 - 0.5 * std::pow(10.0, -3.0 * unit(rng));
        break;
    }
    if (p_of + p_fo == 0.0) continue;
    const double p_occ = unit(rng);
    const double eps = std::pow(10.0, -0.3 - 7.0 * unit(rng));  // [1e-7.3, 0.5]
    // Keep the answer within the brute-force cap.
    const LD sum = static_cast<LD>(p_of) + p_fo;
    const LD rate = sum <= 1.0L ? -std::log1p(-sum) : -std::log1p(sum - 2.0L);
    const LD delta0 = std::fabs(p_occ - static_cast<LD>(p_of) / sum);
    if (delta0 > eps && std::log(delta0 / eps) / rate > 0.9L * kBruteCap) continue;
    if (p_of + p_fo > 1.0) ++oscillating;
    if (delta0 > eps) ++nonzero;
    ++checked;
    if (checkMixingAgainstBrute(p_occ, p_of, p_fo, eps)) ++ties;
    if (HasFailure()) return;
    max_k = std::max(max_k, dog::mixingTime(p_occ, params(p_of, p_fo), eps).value_or(0));
  }
  RecordProperty("checked", checked);
  RecordProperty("ties", ties);
  RecordProperty("max_k", static_cast<int>(max_k));
  EXPECT_GT(max_k, 100000);  // the sweep does reach long mixing times
  EXPECT_GT(checked, 5000);
  EXPECT_GT(nonzero, 4000);
  EXPECT_GT(oscillating, 2000);
  EXPECT_LE(ties, 3);
}

TEST(CellModelMixingTime, StaticCellNeverMixes) {
  for (double q : {0.0, 0.3, 0.5, 1.0}) {
    EXPECT_FALSE(dog::mixingTime(q, params(0.0, 0.0), 0.01).has_value());
    EXPECT_FALSE(dog::mixingTime(q, params(0.0, 0.0), 0.99).has_value());
  }
}

TEST(CellModelMixingTime, LambdaZeroMixesInOneStep) {
  // p_of = 0.25, p_fo = 0.75: lambda = 0, pi = 0.25.
  EXPECT_EQ(dog::mixingTime(0.9, params(0.25, 0.75), 0.01), std::optional<std::int64_t>(1));
  EXPECT_EQ(dog::mixingTime(0.0, params(0.25, 0.75), 1e-9), std::optional<std::int64_t>(1));
  EXPECT_EQ(dog::mixingTime(0.255, params(0.25, 0.75), 0.01), std::optional<std::int64_t>(0));
  EXPECT_EQ(dog::mixingTime(0.25, params(0.25, 0.75), 1e-12), std::optional<std::int64_t>(0));
  // Delta0 == eps exactly (0.5 - 0.25 = 0.25): 0.
  EXPECT_EQ(dog::mixingTime(0.5, params(0.25, 0.75), 0.25), std::optional<std::int64_t>(0));
  EXPECT_EQ(dog::mixingTime(0.9, params(0.5, 0.5), 0.3), std::optional<std::int64_t>(1));
  // pi = 1: Delta0 = 0.1 <= 0.3 from q = 0.9 (0 steps), Delta0 = 0.5 from q = 0.5 (1 step).
  EXPECT_EQ(dog::mixingTime(0.9, params(1.0, 0.0), 0.3), std::optional<std::int64_t>(0));
  EXPECT_EQ(dog::mixingTime(0.5, params(1.0, 0.0), 0.3), std::optional<std::int64_t>(1));
  EXPECT_EQ(dog::mixingTime(0.9, params(0.0, 1.0), 0.3), std::optional<std::int64_t>(1));
  // The brute force agrees.
  EXPECT_EQ(bruteMixingTime(0.9, 0.25, 0.75, 0.01, 10), std::optional<std::int64_t>(1));
}

TEST(CellModelMixingTime, OscillatingCells) {
  // p_of = 0.6, p_fo = 0.7: lambda = -0.3, pi = 6/13.
  for (double q : {0.0, 0.2, 0.9, 1.0}) {
    for (double eps : {0.1, 1e-3, 1e-6, 1e-10}) {
      checkMixingAgainstBrute(q, 0.6, 0.7, eps);
      checkMixingAgainstBrute(q, 0.95, 0.99, eps);  // lambda = -0.94
    }
  }
  // p_of = p_fo = 0.75: lambda = -0.5, pi = 0.5; q = 1: Delta_k = 0.5^(k+1) exactly.
  // eps = 0.5^4: Delta_3 == eps exactly, so the answer is 3 (<=, not <).
  EXPECT_EQ(dog::mixingTime(1.0, params(0.75, 0.75), 0.0625), std::optional<std::int64_t>(3));
  EXPECT_EQ(bruteMixingTime(1.0, 0.75, 0.75, 0.0625, 100), std::optional<std::int64_t>(3));
  EXPECT_EQ(dog::mixingTime(1.0, params(0.75, 0.75), 0.0624), std::optional<std::int64_t>(4));
  EXPECT_EQ(dog::mixingTime(1.0, params(0.75, 0.75), 0.0626), std::optional<std::int64_t>(3));
}

TEST(CellModelMixingTime, ExactBoundaryEqualityCountsAsMixed) {
  // p_of = p_fo = 0.25: lambda = 0.5, pi = 0.5. From q = 1: Delta_k = 0.5^(k+1), exact in
  // binary floating point. Delta_k <= eps first holds at k = n - 1 for eps = 0.5^n.
  // (Evaluating Delta_k as Delta_0 * exp(k * ln|lambda|) can round just above eps and
  // return n instead; Delta_0 * pow(|lambda|, k) is exact for these inputs.)
  for (int n = 1; n <= 40; ++n) {
    const double eps = std::ldexp(1.0, -n);
    if (eps >= 1.0) continue;
    const std::int64_t expected = n - 1;
    ASSERT_EQ(bruteMixingTime(1.0, 0.25, 0.25, eps, 1000), std::optional<std::int64_t>(expected));
    EXPECT_EQ(dog::mixingTime(1.0, params(0.25, 0.25), eps),
              std::optional<std::int64_t>(expected))
        << "eps = 2^-" << n;
    // Same from q = 0 (Delta_0 = 0.5 on the other side).
    EXPECT_EQ(dog::mixingTime(0.0, params(0.25, 0.25), eps),
              std::optional<std::int64_t>(expected))
        << "eps = 2^-" << n;
  }
  // Delta_0 == eps exactly: 0.
  EXPECT_EQ(dog::mixingTime(0.75, params(0.25, 0.25), 0.25), std::optional<std::int64_t>(0));
  EXPECT_EQ(dog::mixingTime(0.25, params(0.25, 0.25), 0.25), std::optional<std::int64_t>(0));
  // Delta_0 < eps: 0.
  EXPECT_EQ(dog::mixingTime(0.6, params(0.25, 0.25), 0.25), std::optional<std::int64_t>(0));
}

TEST(CellModelMixingTime, UnitModulusLambda) {
  // p_of = p_fo = 1: lambda = -1, pi = 0.5, the distance never shrinks.
  EXPECT_FALSE(dog::mixingTime(0.9, params(1.0, 1.0), 0.1).has_value());
  EXPECT_FALSE(dog::mixingTime(0.0, params(1.0, 1.0), 0.49).has_value());
  EXPECT_EQ(dog::mixingTime(0.5, params(1.0, 1.0), 0.1), std::optional<std::int64_t>(0));
  EXPECT_EQ(dog::mixingTime(0.55, params(1.0, 1.0), 0.1), std::optional<std::int64_t>(0));
  EXPECT_EQ(dog::mixingTime(0.75, params(1.0, 1.0), 0.25), std::optional<std::int64_t>(0));
  EXPECT_EQ(dog::mixingTime(0.25, params(1.0, 1.0), 0.25), std::optional<std::int64_t>(0));
  // The brute force confirms: never within eps over the cap.
  EXPECT_FALSE(bruteMixingTime(0.9, 1.0, 1.0, 0.1, 10000).has_value());
}

TEST(CellModelMixingTime, DeltaZeroWithinEpsilon) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  for (int i = 0; i < 500; ++i) {
    const double p_of = unit(rng) * 0.9 + 0.05;
    const double p_fo = unit(rng) * 0.9 + 0.05;
    const double pi = p_of / (p_of + p_fo);
    const double eps = 0.01;
    const double q = pi + (unit(rng) - 0.5) * 0.019;  // |q - pi| < 0.0095
    EXPECT_EQ(dog::mixingTime(q, params(p_of, p_fo), eps), std::optional<std::int64_t>(0));
  }
}

TEST(CellModelMixingTime, VerySlowCell) {
  // p_of + p_fo = 1e-9: lambda rounds to 1 - 1e-9, answer ~ 6.4e9 steps: verify with the
  // closed form in long double: Delta_k <= eps < Delta_{k-1}.
  const struct {
    double q, p_of, p_fo, eps;
  } cases[] = {
      {1.0, 4e-10, 6e-10, 1e-3}, {0.0, 4e-10, 6e-10, 1e-6},  {0.9, 1e-9, 0.0, 0.01},
      {0.2, 0.0, 3e-12, 1e-4},   {1.0, 5e-7, 5e-7, 1e-8},    {0.7, 2e-5, 1e-5, 1e-7},
  };
  for (const auto& c : cases) {
    const auto k = dog::mixingTime(c.q, params(c.p_of, c.p_fo), c.eps);
    ASSERT_TRUE(k.has_value()) << "q=" << c.q << " p_of=" << c.p_of << " p_fo=" << c.p_fo;
    ASSERT_GT(*k, 0);
    const LD at_k = closedFormDelta(c.q, c.p_of, c.p_fo, static_cast<LD>(*k));
    const LD before = closedFormDelta(c.q, c.p_of, c.p_fo, static_cast<LD>(*k - 1));
    EXPECT_LE(at_k, static_cast<LD>(c.eps) * (1.0L + 1e-12L))
        << "q=" << c.q << " p_of=" << c.p_of << " k=" << *k;
    EXPECT_GT(before, static_cast<LD>(c.eps) * (1.0L - 1e-12L))
        << "q=" << c.q << " p_of=" << c.p_of << " k=" << *k;
    // Closed form ceil(ln(eps/Delta0)/ln|lambda|), computed here in long double.
    const LD sum = static_cast<LD>(c.p_of) + c.p_fo;
    const LD delta0 = std::fabs(c.q - static_cast<LD>(c.p_of) / sum);
    const LD k_ref = std::ceil(std::log(static_cast<LD>(c.eps) / delta0) / std::log1p(-sum));
    EXPECT_EQ(static_cast<LD>(*k), k_ref) << "q=" << c.q << " p_of=" << c.p_of;
  }
  // A sanity value: p_of + p_fo = 1e-9, pi = 0.4, q = 1, eps = 1e-3:
  //   k = ceil(ln(600) / -ln(1 - 1e-9)) = ceil(ln(600) / (1e-9 + 5e-19 + ...))
  //     = ceil(6396929655.216 * (1 - 5e-10)) = ceil(6396929652.018) = 6396929653.
  const auto k = dog::mixingTime(1.0, params(4e-10, 6e-10), 1e-3);
  ASSERT_TRUE(k.has_value());
  EXPECT_EQ(*k, std::int64_t{6396929653});
}

TEST(CellModelMixingTime, EpsilonOutsideOpenUnitIntervalThrows) {
  const auto a = params(0.1, 0.2);
  for (double eps : {0.0, -0.1, 1.0, 1.5, -kInf, kInf, std::numeric_limits<double>::quiet_NaN()}) {
    EXPECT_THROW(dog::mixingTime(0.5, a, eps), std::invalid_argument) << "eps=" << eps;
    EXPECT_THROW(dog::mixingTime(0.5, params(0.0, 0.0), eps), std::invalid_argument);
    EXPECT_THROW(dog::mixingTime(0.5, params(1.0, 1.0), eps), std::invalid_argument);
  }
  EXPECT_NO_THROW(dog::mixingTime(0.5, a, 1e-300));
  EXPECT_NO_THROW(dog::mixingTime(0.5, a, 0.999999));
}

// =====================================================================================
// 5. Stationary distribution.
// =====================================================================================

TEST(CellModelStationary, ValueAndFixedPoint) {
  EXPECT_FALSE(dog::stationaryOccupancy(params(0.0, 0.0)).has_value());
  EXPECT_NEAR(*dog::stationaryOccupancy(params(0.1, 0.2)), 1.0 / 3.0, 1e-15);
  EXPECT_NEAR(*dog::stationaryOccupancy(params(0.1, 0.3)), 0.25, 1e-15);
  EXPECT_EQ(*dog::stationaryOccupancy(params(1.0, 1.0)), 0.5);
  EXPECT_EQ(*dog::stationaryOccupancy(params(0.3, 0.0)), 1.0);
  EXPECT_EQ(*dog::stationaryOccupancy(params(0.0, 0.3)), 0.0);
  EXPECT_NEAR(*dog::stationaryOccupancy(params(4e-10, 6e-10)), 0.4, 1e-15);

  std::mt19937_64 rng(77);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  for (int i = 0; i < 2000; ++i) {
    const double p_of = (i % 2 == 0) ? unit(rng) : 1e-3 * unit(rng);
    const double p_fo = unit(rng);
    if (p_of + p_fo == 0.0) continue;
    const auto pi = dog::stationaryOccupancy(params(p_of, p_fo));
    ASSERT_TRUE(pi.has_value());
    const LD expected = static_cast<LD>(p_of) / (static_cast<LD>(p_of) + p_fo);
    ASSERT_NEAR(*pi, static_cast<double>(expected), 1e-15);
    // pi A = pi (reference arithmetic) ...
    const Vec2 next = timesA(Vec2{*pi, 1.0L - *pi}, p_of, p_fo);
    ASSERT_NEAR(static_cast<double>(next.occ), *pi, 1e-14);
    // ... and a fixed point of the code's own prediction.
    ASSERT_NEAR(dog::predictOneStep(*pi, params(p_of, p_fo)), *pi, 1e-14);
    ASSERT_NEAR(dog::predictOccupancy(*pi, params(p_of, p_fo), 1000), *pi, 1e-14);
    // predictOneStep is q A (first component).
    const double q = unit(rng);
    const Vec2 qa = timesA(Vec2{q, 1.0L - q}, p_of, p_fo);
    ASSERT_NEAR(dog::predictOneStep(q, params(p_of, p_fo)), static_cast<double>(qa.occ), 1e-15);
  }
}

TEST(CellModelStationary, TransitionParamsHelpers) {
  EXPECT_TRUE(params(0.0, 0.0).isStatic());
  EXPECT_FALSE(params(1e-300, 0.0).isStatic());
  EXPECT_DOUBLE_EQ(params(0.1, 0.2).lambda(), 0.7);
  EXPECT_DOUBLE_EQ(params(1.0, 1.0).lambda(), -1.0);
  EXPECT_TRUE(params(0.0, 1.0).isValid());
  EXPECT_FALSE(params(-0.1, 0.5).isValid());
  EXPECT_FALSE(params(0.5, 1.1).isValid());
  EXPECT_FALSE(params(std::numeric_limits<double>::quiet_NaN(), 0.5).isValid());
}

// =====================================================================================
// 6. Observation model.
// =====================================================================================

TEST(CellModelObservation, RejectsInvalidProbabilities) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const std::vector<std::pair<double, double>> bad = {
      {0.0, 0.0},  {1.0, 0.2},  {0.7, 0.0},  {1.2, 0.2}, {0.7, -0.1}, {-0.1, -0.2},
      {0.7, 1.0},  {nan, 0.2},  {0.7, nan},  {0.5, 0.5}, {0.2, 0.7},  {0.3, 0.3000001},
      {kInf, 0.2}, {0.7, -kInf}, {1.0, 1.0}, {0.9, 0.9},
  };
  for (const auto& b : bad) {
    EXPECT_THROW(dog::ObservationModel(b.first, b.second), std::invalid_argument)
        << "p_hit_given_occ=" << b.first << " p_hit_given_free=" << b.second;
  }
  EXPECT_NO_THROW(dog::ObservationModel(0.7, 0.2));
  EXPECT_NO_THROW(dog::ObservationModel(0.999999, 1e-6));
  EXPECT_NO_THROW(dog::ObservationModel(0.5000001, 0.5));
}

TEST(CellModelObservation, LogLikelihoodRatioIsLogOfProductOfLikelihoods) {
  const dog::ObservationModel sensor(0.7, 0.2);
  EXPECT_DOUBLE_EQ(sensor.pHitGivenOcc(), 0.7);
  EXPECT_DOUBLE_EQ(sensor.pHitGivenFree(), 0.2);
  EXPECT_NEAR(sensor.hitLogOdds(), std::log(3.5), 1e-15);
  EXPECT_NEAR(sensor.missLogOdds(), std::log(0.375), 1e-15);
  EXPECT_EQ(sensor.logLikelihoodRatio(0, 0), 0.0);

  std::mt19937_64 rng(31337);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_int_distribution<int> count(0, 15);
  for (int i = 0; i < 2000; ++i) {
    double a = unit(rng) * 0.98 + 0.01;
    double b = unit(rng) * 0.98 + 0.01;
    if (a == b) continue;
    if (a < b) std::swap(a, b);
    const dog::ObservationModel s(a, b);
    EXPECT_GT(s.hitLogOdds(), 0.0);
    EXPECT_LT(s.missLogOdds(), 0.0);
    const int h = count(rng);
    const int m = count(rng);
    // p(z|occ) / p(z|free) as a product of per-beam likelihoods.
    LD occ = 1.0L;
    LD free = 1.0L;
    for (int j = 0; j < h; ++j) {
      occ *= a;
      free *= b;
    }
    for (int j = 0; j < m; ++j) {
      occ *= 1.0L - a;
      free *= 1.0L - b;
    }
    const LD expected = std::log(occ / free);
    const double actual = s.logLikelihoodRatio(static_cast<std::uint32_t>(h),
                                               static_cast<std::uint32_t>(m));
    ASSERT_NEAR(actual, static_cast<double>(expected),
                1e-12 * (1.0 + std::fabs(static_cast<double>(expected))))
        << "a=" << a << " b=" << b << " h=" << h << " m=" << m;
  }
}

// A step's likelihood under the mixed-step model, from products in long double: state s
// hits with p, a partly covered cell with an unknown rate (the integral of q^h (1 - q)^m
// over [0, 1] is h! m! / (h + m + 1)!).
long double mixedStepLikelihood(long double p, long double eps, unsigned hits, unsigned misses) {
  long double plain = 1.0L;
  for (unsigned i = 0; i < hits; ++i) plain *= p;
  for (unsigned i = 0; i < misses; ++i) plain *= 1.0L - p;
  long double beta = 1.0L;  // h! m! / (h + m + 1)!: the product of i / (h + i) for i = 1..m, over h + m + 1
  for (unsigned i = 1; i <= misses; ++i) beta *= static_cast<long double>(i) / (hits + i);
  beta /= hits + misses + 1;
  return (1.0L - eps) * plain + eps * beta;
}

TEST(CellModelMixedSteps, DisagreeingStepsMatchAProductReference) {
  for (const auto& [occ, free] : std::vector<std::pair<double, double>>{{0.7, 0.2}, {0.942, 0.01}, {0.99, 0.001}}) {
    for (const double eps : {1e-4, 1e-3, 0.05, 0.5}) {
      const dog::ObservationModel sensor(occ, free, eps);
      EXPECT_EQ(sensor.mixedStepProbability(), eps);
      for (unsigned hits = 1; hits <= 12; ++hits) {
        for (unsigned misses = 1; misses <= 12; ++misses) {
          const long double reference =
              std::log(mixedStepLikelihood(occ, eps, hits, misses) / mixedStepLikelihood(free, eps, hits, misses));
          EXPECT_NEAR(sensor.logLikelihoodRatio(hits, misses), static_cast<double>(reference), 1e-10)
              << occ << " / " << free << " eps " << eps << ": " << hits << " hits, " << misses << " misses";
        }
      }
    }
  }
}

TEST(CellModelMixedSteps, StepsThatAgreeKeepThePlainLikelihoods) {
  const dog::ObservationModel plain(0.942, 0.01);
  const dog::ObservationModel mixed(0.942, 0.01, 1e-3);
  for (std::uint32_t n = 0; n <= 40; ++n) {
    EXPECT_EQ(mixed.logLikelihoodRatio(n, 0), plain.logLikelihoodRatio(n, 0)) << n;
    EXPECT_EQ(mixed.logLikelihoodRatio(0, n), plain.logLikelihoodRatio(0, n)) << n;
  }
  // eps = 0 is the plain model for every step.
  const dog::ObservationModel zero(0.942, 0.01, 0.0);
  EXPECT_EQ(zero.logLikelihoodRatio(3, 7), plain.logLikelihoodRatio(3, 7));
}

TEST(CellModelMixedSteps, ADisagreeingStepIsWeakEvidenceAndCountsStayFinite) {
  // A wall's edge cell under a sharp laser: read plainly, 3 hits and 7 misses say "free"
  // (a likelihood ratio of e^-6.2) and 6 hits and 4 misses "occupied" (e^16); read as
  // possibly mixed, neither says much.
  const dog::ObservationModel plain(0.942, 0.01);
  const dog::ObservationModel mixed(0.942, 0.01, 1e-3);
  EXPECT_LT(plain.logLikelihoodRatio(3, 7), -6.0);
  EXPECT_GT(plain.logLikelihoodRatio(6, 4), 15.0);
  EXPECT_LT(std::abs(mixed.logLikelihoodRatio(3, 7)), 1.0);
  EXPECT_LT(std::abs(mixed.logLikelihoodRatio(6, 4)), 3.0);
  // Many beams (the counts go up to 65535 per step), where every product underflows: against
  // a reference in logs, in long double. An even split of a step that size is the partly
  // covered cell's (the plain terms are e^-90000 below it): no evidence either way.
  const auto log_likelihood = [](long double p, long double eps, long double h, long double m) {
    const long double plain = std::log1p(-eps) + h * std::log(p) + m * std::log1p(-p);
    const long double partly = std::log(eps) + std::lgamma(h + 1.0L) + std::lgamma(m + 1.0L) - std::lgamma(h + m + 2.0L);
    const long double top = std::max(plain, partly);
    return top + std::log1p(std::exp(std::min(plain, partly) - top));
  };
  for (const auto& [hits, misses] : std::vector<std::pair<std::uint32_t, std::uint32_t>>{
           {65535, 1}, {1, 65535}, {65535, 65535}, {40000, 3}, {3000, 2000}}) {
    const long double reference =
        log_likelihood(0.942L, 1e-3L, hits, misses) - log_likelihood(0.01L, 1e-3L, hits, misses);
    EXPECT_NEAR(mixed.logLikelihoodRatio(hits, misses), static_cast<double>(reference),
                1e-9 * std::max(1.0L, std::abs(reference)))
        << hits << " / " << misses;
  }
  EXPECT_EQ(mixed.logLikelihoodRatio(65535, 65535), 0.0);
}

TEST(CellModelMixedSteps, RejectsAProbabilityOutsideZeroToOneHalf) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (const double eps : {-1e-9, 0.5000001, 1.0, nan, kInf}) {
    EXPECT_THROW(dog::ObservationModel(0.7, 0.2, eps), std::invalid_argument) << eps;
  }
  EXPECT_NO_THROW(dog::ObservationModel(0.7, 0.2, 0.5));
}

// =====================================================================================
// 7. No NaN for extreme evidence.
// =====================================================================================

TEST(CellModelRobustness, BayesUpdateNeverNaN) {
  const dog::ObservationModel sensor(0.7, 0.2);
  const dog::ObservationModel sharp(0.999999, 1e-6);
  std::vector<double> ratios = {0.0, 1e-300, -1e-300, 1.0, -1.0, 700.0, -700.0, 710.0, -710.0,
                                1e5, -1e5, 1e300, -1e300, std::numeric_limits<double>::max(),
                                std::numeric_limits<double>::lowest()};
  for (std::uint32_t n : {100u, 300u, 500u, 1000u, 100000u}) {
    ratios.push_back(sensor.logLikelihoodRatio(n, 0));
    ratios.push_back(sensor.logLikelihoodRatio(0, n));
    ratios.push_back(sharp.logLikelihoodRatio(n, 0));
    ratios.push_back(sharp.logLikelihoodRatio(0, n));
    ratios.push_back(sharp.logLikelihoodRatio(n, n / 2));
  }
  const std::vector<double> priors = {0.0,  std::numeric_limits<double>::denorm_min(),
                                      1e-300, 1e-20, 1e-12, 0.5, 1.0 - 1e-12,
                                      std::nextafter(1.0, 0.0), 1.0};
  for (double p : priors) {
    for (double r : ratios) {
      const double post = dog::bayesUpdate(p, r);
      ASSERT_FALSE(std::isnan(post)) << "p=" << p << " r=" << r;
      ASSERT_GE(post, 0.0) << "p=" << p << " r=" << r;
      ASSERT_LE(post, 1.0) << "p=" << p << " r=" << r;
      // Certain beliefs stay certain.
      if (p == 0.0) {
        ASSERT_EQ(post, 0.0);
      }
      if (p == 1.0) {
        ASSERT_EQ(post, 1.0);
      }
      // Direction of the evidence is respected.
      if (r > 0.0) {
        ASSERT_GE(post, p) << "p=" << p << " r=" << r;
      }
      if (r < 0.0) {
        ASSERT_LE(post, p) << "p=" << p << " r=" << r;
      }
      // Through the filter as well, for a few cells including p_of = p_fo = 1 and static.
      for (const auto& c : std::vector<std::pair<double, double>>{
               {0.0, 0.0}, {1.0, 1.0}, {0.1, 0.2}, {1.0, 0.0}, {0.0, 1.0}, {1e-12, 1e-12}}) {
        const double f = dog::filterStep(p, params(c.first, c.second), r);
        ASSERT_FALSE(std::isnan(f)) << "p=" << p << " r=" << r << " cell=" << c.first;
        ASSERT_GE(f, 0.0);
        ASSERT_LE(f, 1.0);
      }
    }
  }
  // Hundreds of hits from an even prior: essentially certain, and finite arithmetic.
  EXPECT_NEAR(dog::bayesUpdate(0.5, sensor.logLikelihoodRatio(500, 0)), 1.0, 1e-15);
  EXPECT_NEAR(dog::bayesUpdate(0.5, sensor.logLikelihoodRatio(0, 500)), 0.0, 1e-15);
  // Tiny prior, moderate evidence: posterior odds o = prior odds * likelihood ratio
  // = 1e-20/(1 - 1e-20) * 3.5^20 ~ 7.61e-10, p = o / (1 + o) (still tiny, not 0, no NaN).
  const double tiny = dog::bayesUpdate(1e-20, sensor.logLikelihoodRatio(20, 0));
  const LD odds = 1e-20L / (1.0L - 1e-20L) * std::pow(3.5L, 20);
  EXPECT_NEAR(tiny, static_cast<double>(odds / (1.0L + odds)), 1e-12 * 7.6e-10);
  // Tiny prior, hundreds of hits: evidence wins.
  EXPECT_NEAR(dog::bayesUpdate(1e-300, sensor.logLikelihoodRatio(1000, 0)), 1.0, 1e-15);
  // 1 - p tiny, hundreds of misses: evidence wins.
  EXPECT_NEAR(dog::bayesUpdate(1.0 - 1e-12, sensor.logLikelihoodRatio(0, 500)), 0.0, 1e-15);
}

TEST(CellModelRobustness, BayesUpdateMatchesOddsFormula) {
  std::mt19937_64 rng(2718);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_real_distribution<double> ratio(-30.0, 30.0);
  for (int i = 0; i < 5000; ++i) {
    const double p = unit(rng);
    const double r = ratio(rng);
    const LD occ = static_cast<LD>(p) * std::exp(static_cast<LD>(r) / 2.0L);
    const LD free = (1.0L - p) * std::exp(-static_cast<LD>(r) / 2.0L);
    ASSERT_NEAR(dog::bayesUpdate(p, r), static_cast<double>(occ / (occ + free)), 1e-14)
        << "p=" << p << " r=" << r;
  }
}
