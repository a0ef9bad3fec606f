// Tests of online EM (core/cell/online_em.h; THEORY.md §6, Mongillo & Deneve 2008 eq. (13)).
//
// The oracle is a plain reference implementation written here in long double: the
// recursion of THEORY.md §6 exactly as stated there (explicit sums over k and m, one loop
// iteration per time step, no closed forms), the prior statistics S(i,j,m) = w a0_ij q(m),
// and the M-step ratio. No reference calls onlineEmStep, onlineEmSkip, priorStats,
// onlineMStep or filterStep. The reference recursion is itself checked against brute-force
// enumeration of all state paths, so it is an independent definition of S.
//
// Index 0 = occ, 1 = free; A = [[1 - p_fo, p_fo], [p_of, 1 - p_of]] (rows: from).

#include "dynamic_occupancy_grid/core/cell/online_em.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace dog = dynamic_occupancy_grid::core;

namespace {

using LD = long double;
using Vec2 = std::array<LD, 2>;
using Mat2 = std::array<Vec2, 2>;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

dog::TransitionParams params(double p_of, double p_fo) {
  dog::TransitionParams t;
  t.p_occ_given_free = p_of;
  t.p_free_given_occ = p_fo;
  return t;
}

std::string describe(const dog::TransitionParams& p) {
  std::ostringstream out;
  out.precision(17);
  out << "p_of=" << p.p_occ_given_free << " p_fo=" << p.p_free_given_occ;
  return out.str();
}

// Bounds wide enough that the M-step never clamps: its raw ratio is observable.
dog::OnlineEmConfig unclampedConfig() {
  dog::OnlineEmConfig config;
  config.p_min = 0.0;
  config.p_max = 1.0;
  return config;
}

// ---- independent reference arithmetic ------------------------------------------------

Mat2 transitionMatrix(const dog::TransitionParams& p) {
  const LD p_of = p.p_occ_given_free;
  const LD p_fo = p.p_free_given_occ;
  return Mat2{Vec2{1.0L - p_fo, p_fo}, Vec2{p_of, 1.0L - p_of}};
}

// b = [p(z|occ), p(z|free)] up to a common factor (only the ratio matters), scaled so the
// larger one is 1: no overflow for any finite ratio. Ratio 0 (no observation) gives [1, 1].
Vec2 likelihoods(double log_likelihood_ratio) {
  const LD l = log_likelihood_ratio;
  return l >= 0.0L ? Vec2{1.0L, std::exp(-l)} : Vec2{std::exp(l), 1.0L};
}

// A cell's statistics S(i,j,m) and filter q = [p(occ), p(free)], in long double. Its own
// [i][j][m] layout, so the reference does not share TransitionStats' indexing.
struct RefCell {
  LD s[2][2][2] = {};
  Vec2 q{0.5L, 0.5L};

  LD total() const {
    LD sum = 0.0L;
    for (int i = 0; i < 2; ++i)
      for (int j = 0; j < 2; ++j)
        for (int m = 0; m < 2; ++m) sum += s[i][j][m];
    return sum;
  }
};

// S_0(i,j,m) = w * a0_ij * q(m).
RefCell refPrior(const dog::TransitionParams& prior, double prior_weight, double p_occ) {
  const Mat2 a0 = transitionMatrix(prior);
  RefCell cell;
  cell.q = Vec2{p_occ, 1.0L - static_cast<LD>(p_occ)};
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j)
      for (int m = 0; m < 2; ++m) cell.s[i][j][m] = prior_weight * a0[i][j] * cell.q[m];
  return cell;
}

// One step of THEORY.md §6, as written there:
//   c = sum_{k,m} q(k) a_km b_m,  r_km = a_km b_m / c,
//   S'(i,j,m) = decay * sum_k S(i,j,k) r_km + delta(j,m) q(i) r_ij,   q'(m) = sum_k q(k) r_km.
void refStep(RefCell& cell, const Mat2& a, const Vec2& b, LD decay) {
  LD c = 0.0L;
  for (int k = 0; k < 2; ++k)
    for (int m = 0; m < 2; ++m) c += cell.q[k] * a[k][m] * b[m];
  LD r[2][2];
  for (int k = 0; k < 2; ++k)
    for (int m = 0; m < 2; ++m) r[k][m] = a[k][m] * b[m] / c;
  RefCell next;
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j)
      for (int m = 0; m < 2; ++m) {
        LD carried = 0.0L;
        for (int k = 0; k < 2; ++k) carried += cell.s[i][j][k] * r[k][m];
        next.s[i][j][m] = decay * carried + (j == m ? cell.q[i] * r[i][j] : 0.0L);
      }
  for (int m = 0; m < 2; ++m) next.q[m] = cell.q[0] * r[0][m] + cell.q[1] * r[1][m];
  cell = next;
}

void refStep(RefCell& cell, const dog::TransitionParams& p, double log_likelihood_ratio,
             double decay) {
  refStep(cell, transitionMatrix(p), likelihoods(log_likelihood_ratio), decay);
}

// `steps` none steps, one at a time.
void refGap(RefCell& cell, const dog::TransitionParams& p, std::int64_t steps, double decay) {
  const Mat2 a = transitionMatrix(p);
  const Vec2 b = likelihoods(0.0);
  for (std::int64_t n = 0; n < steps; ++n) refStep(cell, a, b, decay);
}

// a_ij = sum_m S(i,j,m) / sum_{j,m} S(i,j,m); symmetric: p_c = (T_01 + T_10) / all.
// Then clamped; an empty from-state keeps the fallback.
dog::TransitionParams refMStep(const dog::TransitionStats& stats,
                               const dog::OnlineEmConfig& config,
                               const dog::TransitionParams& fallback) {
  LD transitions[2][2];
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j)
      transitions[i][j] = static_cast<LD>(stats.at(i, j, 0)) + static_cast<LD>(stats.at(i, j, 1));
  const LD from_occ = transitions[0][0] + transitions[0][1];
  const LD from_free = transitions[1][0] + transitions[1][1];
  const auto clamp = [&](LD p) {
    return std::clamp(static_cast<double>(p), config.p_min, config.p_max);
  };
  dog::TransitionParams result = fallback;
  if (config.symmetric) {
    const LD p_change = (transitions[0][1] + transitions[1][0]) / (from_occ + from_free);
    result.p_occ_given_free = result.p_free_given_occ = clamp(p_change);
    return result;
  }
  if (from_occ > 0.0L) result.p_free_given_occ = clamp(transitions[0][1] / from_occ);
  if (from_free > 0.0L) result.p_occ_given_free = clamp(transitions[1][0] / from_free);
  return result;
}

dog::TransitionStats toStats(const RefCell& cell) {
  dog::TransitionStats stats;
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j)
      for (int m = 0; m < 2; ++m) stats.at(i, j, m) = static_cast<double>(cell.s[i][j][m]);
  return stats;
}

RefCell toRef(const dog::TransitionStats& stats, double p_occ) {
  RefCell cell;
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j)
      for (int m = 0; m < 2; ++m) cell.s[i][j][m] = stats.at(i, j, m);
  cell.q = Vec2{p_occ, 1.0L - static_cast<LD>(p_occ)};
  return cell;
}

// All eight entries finite and within rel_tol * (expected total weight) of the reference.
::testing::AssertionResult statsNear(const dog::TransitionStats& actual, const RefCell& expected,
                                     double rel_tol) {
  const LD tolerance = rel_tol * expected.total();
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j)
      for (int m = 0; m < 2; ++m) {
        const double value = actual.at(i, j, m);
        const LD error = std::fabs(static_cast<LD>(value) - expected.s[i][j][m]);
        if (!std::isfinite(value) || !(error <= tolerance)) {
          return ::testing::AssertionFailure()
                 << "S(" << i << "," << j << "," << m << ") = " << value << ", reference "
                 << static_cast<double>(expected.s[i][j][m]) << ", error relative to total "
                 << static_cast<double>(error / std::max(expected.total(), LD{1e-300}));
        }
      }
  return ::testing::AssertionSuccess();
}

// ---- random cells ----------------------------------------------------------------------

struct Random {
  std::mt19937_64 engine;
  explicit Random(std::uint64_t seed) : engine(seed) {}
  double uniform(double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(engine); }
  double logUniform(double lo, double hi) { return std::exp(uniform(std::log(lo), std::log(hi))); }
  std::int64_t integer(std::int64_t lo, std::int64_t hi) {
    return std::uniform_int_distribution<std::int64_t>(lo, hi)(engine);
  }
  bool chance(double p) { return uniform(0.0, 1.0) < p; }
};

// Transitions whose lambda() is exactly `lambda` (in [0, 1)): the closed form's geometric
// sums have d - lambda in a denominator, so decay == lambda is a case of its own.
dog::TransitionParams withLambda(Random& rng, double lambda) {
  const double sum = 1.0 - lambda;  // exact for lambda in [0.5, 1]
  const double share = rng.uniform(0.0, 1.0);
  const auto split = params(share * sum, sum - share * sum);
  // Rounding may move a split's lambda() off by an ulp; (0, sum) always hits it exactly.
  return split.lambda() == lambda ? split : params(0.0, sum);
}

// Transition parameters covering the edge cases of the closed forms (THEORY.md §3): static,
// lambda = 0, lambda < 0, lambda = -1, tiny p_of + p_fo, one of them 0, lambda == decay and
// lambda within 1e-12..1e-6 of the decay, lambda near +-1, typical learned values.
dog::TransitionParams randomParams(Random& rng, double decay) {
  switch (rng.integer(0, 11)) {
    case 0:
      return params(0.0, 0.0);
    case 1: {
      const double p_of = rng.uniform(0.0, 1.0);
      return params(p_of, 1.0 - p_of);  // lambda() == 0 exactly
    }
    case 2:
      return params(rng.uniform(0.5, 1.0), rng.uniform(0.5, 1.0));
    case 3:
      return params(1.0, 1.0);
    case 4:
      return params(rng.uniform(0.0, 1e-12), rng.uniform(0.0, 1e-12));
    case 5: {
      const double p = rng.chance(0.5) ? rng.uniform(0.0, 1.0) : 1.0;
      return rng.chance(0.5) ? params(0.0, p) : params(p, 0.0);
    }
    case 6:
      if (decay < 1.0) return withLambda(rng, decay);
      return params(0.0, 0.0);  // with decay 1, lambda == decay is the static cell
    case 7:
      if (decay < 1.0) {
        const double offset = rng.logUniform(1e-12, 1e-6) * (rng.chance(0.5) ? 1.0 : -1.0);
        return withLambda(rng, std::clamp(decay + offset, 0.5, 1.0 - 1e-15));
      }
      return params(rng.logUniform(1e-9, 1e-6), rng.logUniform(1e-9, 1e-6));
    case 8:  // lambda near -1
      return params(1.0 - rng.logUniform(1e-12, 1e-6), 1.0 - rng.logUniform(1e-12, 1e-6));
    case 9:
      return params(rng.logUniform(1e-4, 0.5), rng.logUniform(1e-4, 0.5));
    default:
      return params(rng.uniform(0.0, 1.0), rng.uniform(0.0, 1.0));
  }
}

double randomBelief(Random& rng) {
  switch (rng.integer(0, 9)) {
    case 0:
      return 0.0;
    case 1:
      return 1.0;
    case 2:
      return 0.5;
    default:
      return rng.uniform(0.0, 1.0);
  }
}

// Evidence of one step: none (ratio 0) about a third of the time.
double randomRatio(Random& rng, double max_abs_ratio) {
  return rng.chance(0.3) ? 0.0 : rng.uniform(-max_abs_ratio, max_abs_ratio);
}

// Statistics as a cell has them: prior pseudo-counts, then some observed steps.
RefCell randomCell(Random& rng, const dog::TransitionParams& filter_params, double decay,
                   int max_steps) {
  // prior_weight 0 is allowed; such a cell gets at least one step so it has some weight.
  const double prior_weight = rng.chance(0.05) ? 0.0 : rng.uniform(0.5, 50.0);
  RefCell cell = refPrior(params(rng.uniform(0.0, 1.0), rng.uniform(0.0, 1.0)), prior_weight,
                          randomBelief(rng));
  const int steps = static_cast<int>(rng.integer(prior_weight == 0.0 ? 1 : 0, max_steps));
  for (int n = 0; n < steps; ++n) refStep(cell, filter_params, randomRatio(rng, 8.0), decay);
  return cell;
}

constexpr std::array<double, 5> kDecays{1.0, 0.9999, 0.999, 0.9, 0.5};

// Largest |ratio| of the chained step tests. With ratios this size the step is well
// conditioned in the double belief it gets (relative error below 1e-16 * e^10 ~ 2e-12),
// so the reference and any correct double implementation agree to 1e-10.
constexpr double kModerateRatio = 10.0;

}  // namespace

// =====================================================================================
// 1. The step kernel and the closed-form gap against the reference recursion.
// =====================================================================================

// THEORY.md §6 "useful fact": a run of none steps in closed form, O(1), must equal the
// recursion applied step by step, to 1e-9 of the statistics' weight, over random cells,
// transition edge cases, decays and gaps up to 1e5.
TEST(OnlineEmSkip, ClosedFormEqualsStepByStepReference) {
  Random rng(20240917);
  constexpr int kCells = 3000;
  for (int cell_index = 0; cell_index < kCells; ++cell_index) {
    const double decay = kDecays[cell_index % kDecays.size()];
    const dog::TransitionParams a = randomParams(rng, decay);
    // Long gaps for about a hundred cells only (the reference walks every step), picked by
    // a modulus prime to the decays' so that every decay gets some.
    std::int64_t gap = 0;
    if (cell_index % 37 == 0) {
      gap = rng.chance(0.2) ? 100000 : rng.integer(10000, 100000);
    } else if (rng.chance(0.2)) {
      gap = rng.integer(0, 10);
    } else if (rng.chance(0.8)) {
      gap = rng.integer(0, 300);
    } else {
      gap = rng.integer(0, 3000);
    }
    const RefCell start = randomCell(rng, a, decay, 6);
    const dog::TransitionStats start_stats = toStats(start);
    const double start_p_occ = static_cast<double>(start.q[0]);

    dog::TransitionStats stats = start_stats;
    const double p_occ = dog::onlineEmSkip(stats, start_p_occ, a, gap, decay);

    RefCell expected = toRef(start_stats, start_p_occ);
    refGap(expected, a, gap, decay);
    ASSERT_TRUE(statsNear(stats, expected, 1e-9))
        << "cell " << cell_index << " " << describe(a) << " decay=" << decay << " gap=" << gap
        << " p_occ=" << start_p_occ;
    ASSERT_NEAR(p_occ, static_cast<double>(expected.q[0]), 1e-9)
        << describe(a) << " gap=" << gap;
    ASSERT_NEAR(p_occ, dog::predictOccupancy(start_p_occ, a, gap), 1e-12)
        << describe(a) << " gap=" << gap;
  }
}

TEST(OnlineEmSkip, ZeroStepsChangesNothing) {
  Random rng(3);
  for (int trial = 0; trial < 200; ++trial) {
    const double decay = kDecays[trial % kDecays.size()];
    const dog::TransitionParams a = randomParams(rng, decay);
    const RefCell start = randomCell(rng, a, decay, 4);
    const dog::TransitionStats start_stats = toStats(start);
    dog::TransitionStats stats = start_stats;
    const double p_occ = static_cast<double>(start.q[0]);
    EXPECT_EQ(dog::onlineEmSkip(stats, p_occ, a, 0, decay), p_occ);
    EXPECT_EQ(stats.s, start_stats.s);
  }
}

// One onlineEmStep from the same double inputs as the reference step, along random chains
// of evidence (positive, negative and none) over the transition edge cases.
TEST(OnlineEmStep, MatchesReferenceRecursion) {
  Random rng(42);
  for (int chain = 0; chain < 1500; ++chain) {
    const double decay = kDecays[chain % kDecays.size()];
    const dog::TransitionParams a = randomParams(rng, decay);
    RefCell state = randomCell(rng, a, decay, 3);
    for (int step = 0; step < 12; ++step) {
      const double ratio = randomRatio(rng, kModerateRatio);
      dog::TransitionStats stats = toStats(state);
      const double p_occ_before = static_cast<double>(state.q[0]);
      const double p_occ = dog::onlineEmStep(stats, p_occ_before, a, ratio, decay);

      RefCell expected = toRef(toStats(state), p_occ_before);
      refStep(expected, a, ratio, decay);
      ASSERT_TRUE(statsNear(stats, expected, 1e-10))
          << describe(a) << " decay=" << decay << " ratio=" << ratio << " step=" << step;
      ASSERT_NEAR(p_occ, static_cast<double>(expected.q[0]), 1e-12) << describe(a);
      state = expected;
    }
  }
}

// Ratios far beyond what exp() of a double can take (+-1000: a few hundred beams in one
// cell and step) must neither overflow nor give NaN, and stay exact. Each transition
// probability is exactly 0, exactly 1 (predictions stay exact) or in [1e-3, 0.999]: with,
// say, p_fo = 1e-12 and evidence e^-200 against the predicted state, the step's result
// depends on the 17th digit of the double belief, and no double implementation could
// match the reference to 1e-10.
TEST(OnlineEmStep, LargeRatiosStayFiniteAndExact) {
  Random rng(99);
  const std::array<double, 6> kLargeRatios{200.0, -200.0, 1000.0, -1000.0, 50.0, -50.0};
  const auto probability = [&rng]() {
    switch (rng.integer(0, 3)) {
      case 0:
        return 0.0;
      case 1:
        return 1.0;
      default:
        return rng.uniform(1e-3, 1.0 - 1e-3);
    }
  };
  for (int chain = 0; chain < 1000; ++chain) {
    const double decay = kDecays[chain % kDecays.size()];
    const dog::TransitionParams a = params(probability(), probability());
    RefCell state = refPrior(params(0.2, 0.3), rng.uniform(0.5, 20.0), rng.uniform(0.05, 0.95));
    for (int step = 0; step < 6; ++step) {
      // With a transition probability of exactly 0 or 1 the prediction can put all weight
      // on one state, so a belief rounded to exactly 0 or 1 by the previous large ratio
      // stays so, and an opposing ratio is again ill-conditioned: those get one step each.
      if (step > 0 && !(a.p_occ_given_free > 0.0 && a.p_occ_given_free < 1.0 &&
                        a.p_free_given_occ > 0.0 && a.p_free_given_occ < 1.0)) {
        break;
      }
      const double ratio = rng.chance(0.2) ? 0.0 : kLargeRatios[rng.integer(0, 5)];
      dog::TransitionStats stats = toStats(state);
      const double p_occ_before = static_cast<double>(state.q[0]);
      const double p_occ = dog::onlineEmStep(stats, p_occ_before, a, ratio, decay);

      RefCell expected = toRef(toStats(state), p_occ_before);
      refStep(expected, a, ratio, decay);
      ASSERT_TRUE(std::isfinite(p_occ)) << describe(a) << " ratio=" << ratio;
      ASSERT_TRUE(statsNear(stats, expected, 1e-10))
          << describe(a) << " decay=" << decay << " ratio=" << ratio << " step=" << step
          << " p_occ=" << p_occ_before;
      ASSERT_NEAR(p_occ, static_cast<double>(expected.q[0]), 1e-12) << describe(a);
      state = expected;
    }
  }
}

// =====================================================================================
// 2. The belief the step returns is the filter of THEORY.md §2.
// =====================================================================================

TEST(OnlineEmStep, ReturnedBeliefIsFilterStep) {
  Random rng(7);
  const std::array<double, 4> kLargeRatios{200.0, -200.0, 1000.0, -1000.0};
  for (int trial = 0; trial < 5000; ++trial) {
    const double decay = kDecays[trial % kDecays.size()];
    const dog::TransitionParams a = randomParams(rng, decay);
    const double ratio =
        rng.chance(0.1) ? kLargeRatios[rng.integer(0, 3)] : randomRatio(rng, kModerateRatio);
    const RefCell start = randomCell(rng, a, decay, 3);
    dog::TransitionStats stats = toStats(start);
    const double p_occ = static_cast<double>(start.q[0]);
    EXPECT_NEAR(dog::onlineEmStep(stats, p_occ, a, ratio, decay), dog::filterStep(p_occ, a, ratio),
                1e-12)
        << describe(a) << " p_occ=" << p_occ << " ratio=" << ratio;
  }
}

// =====================================================================================
// 3. What S means: posterior transition sums, by enumeration of all state paths.
// =====================================================================================

// With fixed transitions, after T steps
//   S_T(i,j,m) = d^T w a0_ij q_T(m) + sum_{tau=1..T} d^(T-tau) p(x_{tau-1}=i, x_tau=j, x_T=m | z_1:T),
// where the posterior is computed by summing the joint probability of every state path
// x_0..x_T with x_0 ~ q_0. Checks the kernel and, at the same time, the reference recursion
// every other test relies on.
TEST(OnlineEmStep, StatisticsArePathPosteriorSums) {
  Random rng(2718);
  for (int trial = 0; trial < 1500; ++trial) {
    const double decay = trial % 3 == 0 ? 0.9 : 1.0;
    const dog::TransitionParams a = randomParams(rng, decay);
    const dog::TransitionParams prior = params(rng.uniform(0.0, 1.0), rng.uniform(0.0, 1.0));
    const double prior_weight = rng.uniform(0.0, 20.0);
    const double q0_occ = rng.uniform(0.01, 0.99);
    const int steps = static_cast<int>(rng.integer(1, 8));
    std::vector<double> ratios(static_cast<std::size_t>(steps) + 1, 0.0);  // ratios[tau], tau >= 1
    for (int tau = 1; tau <= steps; ++tau) ratios[tau] = randomRatio(rng, 5.0);

    // Brute force over all 2^(T+1) paths.
    const Mat2 am = transitionMatrix(a);
    const Vec2 q0{q0_occ, 1.0L - static_cast<LD>(q0_occ)};
    LD joint_sum = 0.0L;
    LD transition_mass[2][2][2] = {};  // sum_tau d^(T-tau) p(i, j, x_T = m, z)
    LD final_mass[2] = {};             // p(x_T = m, z)
    for (int path = 0; path < (1 << (steps + 1)); ++path) {
      const auto state = [path](int tau) { return (path >> tau) & 1; };
      LD weight = q0[state(0)];
      for (int tau = 1; tau <= steps; ++tau) {
        weight *= am[state(tau - 1)][state(tau)] * likelihoods(ratios[tau])[state(tau)];
      }
      joint_sum += weight;
      final_mass[state(steps)] += weight;
      for (int tau = 1; tau <= steps; ++tau) {
        transition_mass[state(tau - 1)][state(tau)][state(steps)] +=
            std::pow(static_cast<LD>(decay), steps - tau) * weight;
      }
    }
    const Mat2 a0 = transitionMatrix(prior);
    RefCell brute;
    for (int m = 0; m < 2; ++m) brute.q[m] = final_mass[m] / joint_sum;
    for (int i = 0; i < 2; ++i)
      for (int j = 0; j < 2; ++j)
        for (int m = 0; m < 2; ++m) {
          brute.s[i][j][m] = std::pow(static_cast<LD>(decay), steps) * prior_weight * a0[i][j] *
                                 brute.q[m] +
                             transition_mass[i][j][m] / joint_sum;
        }

    dog::TransitionStats stats = dog::priorStats(prior, prior_weight, q0_occ);
    double p_occ = q0_occ;
    RefCell reference = refPrior(prior, prior_weight, q0_occ);
    for (int tau = 1; tau <= steps; ++tau) {
      p_occ = dog::onlineEmStep(stats, p_occ, a, ratios[tau], decay);
      refStep(reference, a, ratios[tau], decay);
    }
    const dog::TransitionStats reference_stats = toStats(reference);
    ASSERT_TRUE(statsNear(reference_stats, brute, 1e-12)) << "reference, " << describe(a);
    ASSERT_TRUE(statsNear(stats, brute, 1e-12))
        << describe(a) << " steps=" << steps << " decay=" << decay;
    ASSERT_NEAR(p_occ, static_cast<double>(brute.q[0]), 1e-12) << describe(a);
  }
}

// =====================================================================================
// 4. THEORY.md §6 "useful fact": a none step leaves the M-step where it is.
// =====================================================================================

TEST(OnlineEmMStep, NoneStepLeavesMStepUnchanged) {
  const dog::OnlineEmConfig plain = unclampedConfig();
  dog::OnlineEmConfig symmetric = unclampedConfig();
  symmetric.symmetric = true;
  // Default bounds [1e-4, 0.5]; the cells below learn outside them, so the clamp is active.
  const dog::OnlineEmConfig clamped;
  dog::OnlineEmConfig clamped_symmetric;
  clamped_symmetric.symmetric = true;

  struct Case {
    const char* name;
    dog::OnlineEmConfig config;
    bool clamp_active;
  };
  const std::array<Case, 4> cases{Case{"plain", plain, false},
                                  Case{"symmetric", symmetric, false},
                                  Case{"clamped", clamped, true},
                                  Case{"clamped symmetric", clamped_symmetric, true}};
  const auto fallback = params(0.3, 0.3);
  Random rng(1234);
  for (const Case& c : cases) {
    for (int trial = 0; trial < 500; ++trial) {
      const double decay = kDecays[trial % kDecays.size()];
      // Clamp active: cells that learn p_fo > 0.5 (and a tiny p_of), or symmetric p_c > 0.5.
      dog::TransitionParams generator = params(rng.uniform(0.01, 0.9), rng.uniform(0.01, 0.9));
      double prior_weight = rng.uniform(0.5, 30.0);
      if (c.clamp_active) {
        generator = c.config.symmetric ? params(rng.uniform(0.9, 1.0), rng.uniform(0.9, 1.0))
                                       : params(rng.uniform(0.0, 1e-5), rng.uniform(0.9, 1.0));
        prior_weight = rng.uniform(5.0, 30.0);  // so the few steps below stay outside
      }
      RefCell start = refPrior(generator, prior_weight, rng.uniform(0.0, 1.0));
      const int steps = static_cast<int>(rng.integer(0, 6));
      for (int n = 0; n < steps; ++n) refStep(start, generator, randomRatio(rng, 4.0), decay);
      const dog::TransitionStats start_stats = toStats(start);
      const double p_occ = static_cast<double>(start.q[0]);

      const dog::TransitionParams learned = dog::onlineMStep(start_stats, c.config, fallback);
      if (c.clamp_active) {
        dog::OnlineEmConfig no_clamp = unclampedConfig();
        no_clamp.symmetric = c.config.symmetric;
        const dog::TransitionParams raw = refMStep(start_stats, no_clamp, fallback);
        ASSERT_GT(raw.p_free_given_occ, c.config.p_max) << c.name << ": clamp not exercised";
      }

      dog::TransitionStats after_step = start_stats;
      dog::onlineEmStep(after_step, p_occ, learned, 0.0, decay);
      const dog::TransitionParams relearned = dog::onlineMStep(after_step, c.config, fallback);
      EXPECT_NEAR(relearned.p_occ_given_free, learned.p_occ_given_free, 1e-12) << c.name;
      EXPECT_NEAR(relearned.p_free_given_occ, learned.p_free_given_occ, 1e-12) << c.name;

      // Hence a whole gap can be crossed with the transitions fixed.
      dog::TransitionStats after_gap = start_stats;
      dog::onlineEmSkip(after_gap, p_occ, learned, rng.integer(1, 100000), decay);
      const dog::TransitionParams after_gap_learned = dog::onlineMStep(after_gap, c.config, fallback);
      EXPECT_NEAR(after_gap_learned.p_occ_given_free, learned.p_occ_given_free, 1e-12) << c.name;
      EXPECT_NEAR(after_gap_learned.p_free_given_occ, learned.p_free_given_occ, 1e-12) << c.name;
    }
  }
}

// From prior statistics with params = a0 (so onlineMStep(stats) == params), one step with
// evidence b gives a'_ij = a_ij (d w + q(i) b_j / c) / (d w + q(i) (A b)_i / c): evidence
// for "occupied" (b_occ > b_free) raises p_of and lowers p_fo. Symmetric: p_c' = p_c (2dw +
// (q_occ b_free + q_free b_occ) / c) / (2dw + 1), which falls when the evidence agrees with
// the belief (q_occ > 1/2, b_occ > b_free) and is unchanged at q = [1/2, 1/2].
TEST(OnlineEmMStep, EvidenceMovesTheEstimate) {
  const auto prior = params(0.2, 0.3);
  const dog::OnlineEmConfig plain = unclampedConfig();
  dog::TransitionStats stats = dog::priorStats(prior, 10.0, 0.8);
  dog::onlineEmStep(stats, 0.8, prior, 2.0, 0.999);
  const dog::TransitionParams learned = dog::onlineMStep(stats, plain, prior);
  EXPECT_GT(learned.p_occ_given_free, 0.2 + 1e-3);
  EXPECT_LT(learned.p_free_given_occ, 0.3 - 1e-3);
  // And by the exact amount above (b = [e^2, 1], computed in long double).
  const LD w = 10.0L * 0.999L;
  const LD e2 = std::exp(2.0L);
  const LD c = 0.8L * (0.7L * e2 + 0.3L) + 0.2L * (0.2L * e2 + 0.8L);
  const LD p_of = 0.2L * (w + 0.2L * e2 / c) / (w + 0.2L * (0.2L * e2 + 0.8L) / c);
  const LD p_fo = 0.3L * (w + 0.8L / c) / (w + 0.8L * (0.7L * e2 + 0.3L) / c);
  EXPECT_NEAR(learned.p_occ_given_free, static_cast<double>(p_of), 1e-12);
  EXPECT_NEAR(learned.p_free_given_occ, static_cast<double>(p_fo), 1e-12);

  dog::OnlineEmConfig symmetric = unclampedConfig();
  symmetric.symmetric = true;
  const auto changing = params(0.25, 0.25);
  dog::TransitionStats sym_stats = dog::priorStats(changing, 10.0, 0.8);
  dog::onlineEmStep(sym_stats, 0.8, changing, 2.0, 0.999);
  const dog::TransitionParams sym_learned = dog::onlineMStep(sym_stats, symmetric, changing);
  const LD sym_c = 0.8L * (0.75L * e2 + 0.25L) + 0.2L * (0.25L * e2 + 0.75L);
  const LD p_c = 0.25L * (2.0L * w + (0.8L + 0.2L * e2) / sym_c) / (2.0L * w + 1.0L);
  EXPECT_LT(sym_learned.p_occ_given_free, 0.25 - 1e-3);
  EXPECT_NEAR(sym_learned.p_occ_given_free, static_cast<double>(p_c), 1e-12);
  EXPECT_EQ(sym_learned.p_free_given_occ, sym_learned.p_occ_given_free);

  dog::TransitionStats even_stats = dog::priorStats(changing, 10.0, 0.5);
  dog::onlineEmStep(even_stats, 0.5, changing, 2.0, 0.999);
  EXPECT_NEAR(dog::onlineMStep(even_stats, symmetric, changing).p_occ_given_free, 0.25, 1e-12);
}

// =====================================================================================
// 5. Prior statistics.
// =====================================================================================

TEST(OnlineEmPrior, PriorStatsAreTheDocumentedPseudoCounts) {
  Random rng(5);
  const dog::OnlineEmConfig plain = unclampedConfig();
  const auto fallback = params(0.37, 0.41);
  for (int trial = 0; trial < 1000; ++trial) {
    const auto prior = params(rng.uniform(0.0, 1.0), rng.uniform(0.0, 1.0));
    const double w = rng.uniform(0.1, 100.0);
    const double p_occ = randomBelief(rng);
    const dog::TransitionStats stats = dog::priorStats(prior, w, p_occ);
    EXPECT_TRUE(statsNear(stats, refPrior(prior, w, p_occ), 1e-15));
    EXPECT_NEAR(stats.total(), 2.0 * w, 1e-13 * w);
    // The m-marginal is the belief: sum_{i,j} S(i,j,m) = 2 w q(m).
    const Vec2 q{p_occ, 1.0L - static_cast<LD>(p_occ)};
    for (int m = 0; m < 2; ++m) {
      const double marginal = stats.at(0, 0, m) + stats.at(0, 1, m) + stats.at(1, 0, m) +
                              stats.at(1, 1, m);
      EXPECT_NEAR(marginal, static_cast<double>(2.0L * w * q[m]), 1e-13 * w);
    }
    // Each from-state carries w pseudo-transitions.
    EXPECT_NEAR(stats.transitions(0, 0) + stats.transitions(0, 1), w, 1e-13 * w);
    EXPECT_NEAR(stats.transitions(1, 0) + stats.transitions(1, 1), w, 1e-13 * w);
    // Its M-step gives the prior back.
    const dog::TransitionParams learned = dog::onlineMStep(stats, plain, fallback);
    EXPECT_NEAR(learned.p_occ_given_free, prior.p_occ_given_free, 1e-14);
    EXPECT_NEAR(learned.p_free_given_occ, prior.p_free_given_occ, 1e-14);
  }
}

TEST(OnlineEmPrior, TotalAndTransitionsSumTheEntries) {
  dog::TransitionStats stats;
  for (int n = 0; n < 8; ++n) stats.s[static_cast<std::size_t>(n)] = 1 << n;  // distinct bits
  EXPECT_EQ(stats.total(), 255.0);
  EXPECT_EQ(stats.transitions(0, 1), stats.at(0, 1, 0) + stats.at(0, 1, 1));
  EXPECT_EQ(stats.transitions(1, 0), stats.at(1, 0, 0) + stats.at(1, 0, 1));
  EXPECT_EQ(dog::TransitionStats{}.total(), 0.0);
}

// =====================================================================================
// 6. The M-step by hand.
// =====================================================================================

namespace {

// Expected transitions T(0,0) = 6, T(0,1) = 2 (from occ: 8), T(1,0) = 1, T(1,1) = 9
// (from free: 10), split unevenly over the current state m (the M-step sums over m).
dog::TransitionStats handStats() {
  dog::TransitionStats stats;
  const double transitions[2][2] = {{6.0, 2.0}, {1.0, 9.0}};
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j) {
      stats.at(i, j, 0) = 0.25 * transitions[i][j];
      stats.at(i, j, 1) = 0.75 * transitions[i][j];
    }
  return stats;
}

}  // namespace

TEST(OnlineEmMStep, HandComputedRatios) {
  const auto fallback = params(0.37, 0.41);
  dog::OnlineEmConfig config = unclampedConfig();
  const dog::TransitionParams plain = dog::onlineMStep(handStats(), config, fallback);
  EXPECT_NEAR(plain.p_free_given_occ, 2.0 / 8.0, 1e-15);
  EXPECT_NEAR(plain.p_occ_given_free, 1.0 / 10.0, 1e-15);

  // Symmetric: (2 + 1) / (8 + 10) = 1/6, not the mean of the two ratios (0.175).
  config.symmetric = true;
  const dog::TransitionParams symmetric = dog::onlineMStep(handStats(), config, fallback);
  EXPECT_NEAR(symmetric.p_occ_given_free, 1.0 / 6.0, 1e-15);
  EXPECT_NEAR(symmetric.p_free_given_occ, 1.0 / 6.0, 1e-15);
}

TEST(OnlineEmMStep, ClampsOnBothSides) {
  const auto fallback = params(0.17, 0.17);
  dog::OnlineEmConfig config;
  config.p_min = 0.15;
  config.p_max = 0.2;
  // Raw p_fo = 0.25 > p_max, raw p_of = 0.1 < p_min.
  const dog::TransitionParams plain = dog::onlineMStep(handStats(), config, fallback);
  EXPECT_EQ(plain.p_free_given_occ, 0.2);
  EXPECT_EQ(plain.p_occ_given_free, 0.15);

  config.symmetric = true;  // raw 1/6, inside [0.15, 0.2]
  EXPECT_NEAR(dog::onlineMStep(handStats(), config, fallback).p_occ_given_free, 1.0 / 6.0, 1e-15);
  config.p_max = 0.12;
  config.p_min = 0.1;
  const dog::TransitionParams above = dog::onlineMStep(handStats(), config, fallback);
  EXPECT_EQ(above.p_occ_given_free, 0.12);
  EXPECT_EQ(above.p_free_given_occ, 0.12);
  config.p_min = 0.18;
  config.p_max = 0.3;
  const dog::TransitionParams below = dog::onlineMStep(handStats(), config, fallback);
  EXPECT_EQ(below.p_occ_given_free, 0.18);
  EXPECT_EQ(below.p_free_given_occ, 0.18);
}

TEST(OnlineEmMStep, FromStateWithoutWeightKeepsFallback) {
  const auto fallback = params(0.37, 0.41);
  const dog::OnlineEmConfig config = unclampedConfig();

  dog::TransitionStats no_occ = handStats();
  for (int j = 0; j < 2; ++j)
    for (int m = 0; m < 2; ++m) no_occ.at(0, j, m) = 0.0;
  const dog::TransitionParams from_free_only = dog::onlineMStep(no_occ, config, fallback);
  EXPECT_EQ(from_free_only.p_free_given_occ, 0.41);
  EXPECT_NEAR(from_free_only.p_occ_given_free, 0.1, 1e-15);

  dog::TransitionStats no_free = handStats();
  for (int j = 0; j < 2; ++j)
    for (int m = 0; m < 2; ++m) no_free.at(1, j, m) = 0.0;
  const dog::TransitionParams from_occ_only = dog::onlineMStep(no_free, config, fallback);
  EXPECT_EQ(from_occ_only.p_occ_given_free, 0.37);
  EXPECT_NEAR(from_occ_only.p_free_given_occ, 0.25, 1e-15);

  const dog::TransitionParams empty = dog::onlineMStep(dog::TransitionStats{}, config, fallback);
  EXPECT_EQ(empty.p_occ_given_free, 0.37);
  EXPECT_EQ(empty.p_free_given_occ, 0.41);
}

// =====================================================================================
// 7. Configuration.
// =====================================================================================

TEST(OnlineEmConfig, DefaultsAreValid) {
  const dog::OnlineEmConfig defaults;
  EXPECT_NO_THROW(defaults.validate());
  EXPECT_DOUBLE_EQ(defaults.decay(), 1.0 - defaults.learning_rate_floor);

  dog::OnlineEmConfig edges;
  edges.learning_rate_floor = 0.0;  // plain running sums
  edges.p_min = 0.0;
  edges.p_max = 1.0;
  EXPECT_NO_THROW(edges.validate());
  edges.p_min = edges.p_max = 0.3;  // a fixed value
  EXPECT_NO_THROW(edges.validate());
}

TEST(OnlineEmConfig, ValidateRejectsBadFields) {
  using Mutation = void (*)(dog::OnlineEmConfig&);
  const std::vector<std::pair<const char*, Mutation>> bad{
      {"negative prior_weight", [](dog::OnlineEmConfig& c) { c.prior_weight = -1.0; }},
      {"NaN prior_weight", [](dog::OnlineEmConfig& c) { c.prior_weight = kNaN; }},
      {"infinite prior_weight", [](dog::OnlineEmConfig& c) { c.prior_weight = kInf; }},
      {"negative learning_rate_floor", [](dog::OnlineEmConfig& c) { c.learning_rate_floor = -1e-9; }},
      {"learning_rate_floor 1", [](dog::OnlineEmConfig& c) { c.learning_rate_floor = 1.0; }},
      {"learning_rate_floor > 1", [](dog::OnlineEmConfig& c) { c.learning_rate_floor = 2.0; }},
      {"NaN learning_rate_floor", [](dog::OnlineEmConfig& c) { c.learning_rate_floor = kNaN; }},
      {"negative p_min", [](dog::OnlineEmConfig& c) { c.p_min = -1e-9; }},
      {"p_max > 1", [](dog::OnlineEmConfig& c) { c.p_max = 1.0 + 1e-9; }},
      {"p_min > p_max", [](dog::OnlineEmConfig& c) {
         c.p_min = 0.3;
         c.p_max = 0.2;
       }},
      {"NaN p_min", [](dog::OnlineEmConfig& c) { c.p_min = kNaN; }},
      {"NaN p_max", [](dog::OnlineEmConfig& c) { c.p_max = kNaN; }},
  };
  for (const auto& [name, mutate] : bad) {
    dog::OnlineEmConfig config;
    mutate(config);
    EXPECT_THROW(config.validate(), std::invalid_argument) << name;
  }
}

// =====================================================================================
// 8. One cell's learner as the Mapper runs it.
// =====================================================================================

TEST(OnlineCell, NewCellStartsFromPrior) {
  dog::OnlineEmConfig config;
  config.prior_weight = 7.0;
  const auto prior = params(0.1, 0.2);
  const dog::OnlineCell cell = dog::newOnlineCell(prior, 0.3, config);
  EXPECT_EQ(cell.p_occ, 0.3);
  EXPECT_EQ(cell.observed_steps, 0u);
  EXPECT_EQ(cell.params.p_occ_given_free, 0.1);
  EXPECT_EQ(cell.params.p_free_given_occ, 0.2);
  EXPECT_TRUE(statsNear(cell.stats, refPrior(prior, 7.0, 0.3), 1e-15));
}

// Each call: the gap's none steps, then the observed step, both with the transitions the
// filter had before the call; then the prior again until min_observed_steps observed steps,
// the M-step of the new statistics from then on.
TEST(OnlineCell, LearnStepIsGapThenObservedStepThenMStep) {
  Random rng(31337);
  for (int run = 0; run < 120; ++run) {
    dog::OnlineEmConfig config;
    config.symmetric = run % 2 == 1;
    config.learning_rate_floor = 1.0 - kDecays[(run / 2) % kDecays.size()];
    config.min_observed_steps = static_cast<std::uint32_t>(rng.integer(0, 6));
    config.prior_weight = rng.uniform(0.5, 20.0);
    const auto prior = params(rng.logUniform(1e-3, 0.4), rng.logUniform(1e-3, 0.4));
    dog::OnlineCell cell = dog::newOnlineCell(prior, rng.uniform(0.0, 1.0), config);
    for (std::uint32_t call = 0; call < 25; ++call) {
      const std::int64_t gap = rng.chance(0.1) ? rng.integer(0, 5000) : rng.integer(0, 20);
      const double ratio = rng.uniform(-6.0, 6.0);
      const dog::OnlineCell before = cell;
      dog::onlineLearnStep(cell, gap, ratio, prior, config);

      RefCell expected = toRef(before.stats, before.p_occ);
      refGap(expected, before.params, gap, config.decay());
      refStep(expected, before.params, ratio, config.decay());
      ASSERT_TRUE(statsNear(cell.stats, expected, 1e-9))
          << "run " << run << " call " << call << " gap=" << gap;
      ASSERT_NEAR(cell.p_occ, static_cast<double>(expected.q[0]), 1e-9) << "call " << call;
      ASSERT_EQ(cell.observed_steps, call + 1);
      if (cell.observed_steps < config.min_observed_steps) {
        ASSERT_EQ(cell.params.p_occ_given_free, prior.p_occ_given_free) << "call " << call;
        ASSERT_EQ(cell.params.p_free_given_occ, prior.p_free_given_occ) << "call " << call;
      } else {
        const dog::TransitionParams learned = refMStep(cell.stats, config, prior);
        ASSERT_NEAR(cell.params.p_occ_given_free, learned.p_occ_given_free, 1e-12)
            << "run " << run << " call " << call;
        ASSERT_NEAR(cell.params.p_free_given_occ, learned.p_free_given_occ, 1e-12)
            << "run " << run << " call " << call;
      }
    }
  }
}

TEST(OnlineCell, FirstStepsFilterWithThePrior) {
  dog::OnlineEmConfig config;
  config.min_observed_steps = 2;
  const auto prior = params(0.05, 0.1);
  dog::OnlineCell cell = dog::newOnlineCell(prior, 0.4, config);
  // Gap of 3 none steps, then a hit-like ratio, all with the prior transitions.
  const double expected = dog::filterStep(dog::predictOccupancy(0.4, prior, 3), prior, 2.5);
  dog::onlineLearnStep(cell, 3, 2.5, prior, config);
  EXPECT_NEAR(cell.p_occ, expected, 1e-12);
  EXPECT_EQ(cell.params.p_occ_given_free, prior.p_occ_given_free);
  EXPECT_EQ(cell.params.p_free_given_occ, prior.p_free_given_occ);
  // The second observed step reaches min_observed_steps: the M-step takes over.
  dog::onlineLearnStep(cell, 0, -2.5, prior, config);
  EXPECT_EQ(cell.observed_steps, 2u);
  const dog::TransitionParams learned = dog::onlineMStep(cell.stats, config, prior);
  EXPECT_EQ(cell.params.p_occ_given_free, learned.p_occ_given_free);
  EXPECT_EQ(cell.params.p_free_given_occ, learned.p_free_given_occ);
  EXPECT_NE(cell.params.p_occ_given_free, prior.p_occ_given_free);
}

TEST(OnlineCell, NoMinimumUsesTheMStepAfterEveryStep) {
  dog::OnlineEmConfig config;
  config.min_observed_steps = 0;
  const auto prior = params(0.05, 0.1);
  dog::OnlineCell cell = dog::newOnlineCell(prior, 0.5, config);
  Random rng(8);
  for (int call = 0; call < 10; ++call) {
    dog::onlineLearnStep(cell, rng.integer(0, 10), rng.uniform(-3.0, 3.0), prior, config);
    const dog::TransitionParams learned = dog::onlineMStep(cell.stats, config, prior);
    EXPECT_EQ(cell.params.p_occ_given_free, learned.p_occ_given_free) << "call " << call;
    EXPECT_EQ(cell.params.p_free_given_occ, learned.p_free_given_occ) << "call " << call;
  }
  EXPECT_NE(cell.params.p_occ_given_free, prior.p_occ_given_free);
}

// =====================================================================================
// 9. Consistency: a simulated cell's transitions are learned.
// =====================================================================================

// 20000 steps of a cell with p_of = 0.05, p_fo = 0.1, observed every step by a sensor with
// p(hit|occ) = p(miss|free) = 1/(1+e^-3) (ratios +-3), plain running sums (decay 1).
// Over 300 seeds the learned values have an rms error of about 0.003 (p_of) and 0.005
// (p_fo), so 0.01 is about two standard errors of p_fo: the seed is fixed, and this seed
// gives errors of about 0.0005 and 0.0046. The uniform draws are built from the engine's
// bits because std::uniform_real_distribution differs between standard libraries.
TEST(OnlineCell, LearnsTheTransitionsOfASimulatedCell) {
  constexpr double kTrueOccGivenFree = 0.05;
  constexpr double kTrueFreeGivenOcc = 0.1;
  constexpr double kRatio = 3.0;
  const double p_hit_given_occ = 1.0 / (1.0 + std::exp(-kRatio));
  dog::OnlineEmConfig config;
  config.learning_rate_floor = 0.0;
  config.validate();
  const auto prior = params(0.2, 0.2);

  std::mt19937_64 engine(20250101);
  const auto unit = [&engine]() { return static_cast<double>(engine() >> 11) * 0x1.0p-53; };
  bool occupied = unit() < kTrueOccGivenFree / (kTrueOccGivenFree + kTrueFreeGivenOcc);
  dog::OnlineCell cell = dog::newOnlineCell(prior, 0.5, config);
  for (int step = 0; step < 20000; ++step) {
    occupied = occupied ? unit() >= kTrueFreeGivenOcc : unit() < kTrueOccGivenFree;
    const bool hit = unit() < (occupied ? p_hit_given_occ : 1.0 - p_hit_given_occ);
    dog::onlineLearnStep(cell, 0, hit ? kRatio : -kRatio, prior, config);
  }
  EXPECT_EQ(cell.observed_steps, 20000u);
  EXPECT_NEAR(cell.params.p_occ_given_free, kTrueOccGivenFree, 0.01);
  EXPECT_NEAR(cell.params.p_free_given_occ, kTrueFreeGivenOcc, 0.01);
}
