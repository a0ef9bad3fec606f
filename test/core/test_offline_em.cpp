// Tests of the offline EM (Baum–Welch) of THEORY.md §5 (core/cell/offline_em.h).
//
// The optimized forward–backward crosses runs of steps without observation in closed form.
// Every reference value below is computed independently of it, in long double, by a plain
// scaled forward–backward over the *expanded* sequence: every step from the one before the
// cell's first observation (where p(occ) = initial_p_occ) to its last observed step is
// written out, steps without observation with likelihood 1 for both states, and
//   A = [ 1 - p_fo   p_fo     ]
//       [ p_of       1 - p_of ]   (index 0 = occ, 1 = free).
// The reference M-step and EM loop are written from the header's promises; no reference
// calls forwardBackward, offlineMStep or runOfflineEm.

#include "dynamic_occupancy_grid/core/cell/offline_em.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <optional>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace dog = dynamic_occupancy_grid::core;

namespace {

using LD = long double;
using Sequence = std::vector<dog::StepObservation>;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

dog::TransitionParams params(double p_of, double p_fo) {
  dog::TransitionParams t;
  t.p_occ_given_free = p_of;
  t.p_free_given_occ = p_fo;
  return t;
}

dog::StepObservation observation(std::int32_t step, int hits, int misses) {
  return dog::StepObservation{step, static_cast<std::uint16_t>(hits),
                              static_cast<std::uint16_t>(misses)};
}

// ---- independent reference: plain forward–backward over the expanded sequence ---------

struct Matrix2 {
  LD a[2][2];
};

Matrix2 transitionMatrix(const dog::TransitionParams& p) {
  const LD p_of = p.p_occ_given_free;
  const LD p_fo = p.p_free_given_occ;
  return Matrix2{{{1.0L - p_fo, p_fo}, {p_of, 1.0L - p_of}}};
}

// The likelihoods [p(z|occ), p(z|free)] of `hits` hits and `misses` misses, divided by their
// larger entry so that 65535 fused beams stay representable; the divisor's log is returned
// in `log_scale` and added back to the log-likelihood.
void scaledLikelihoods(const dog::ObservationModel& sensor, int hits, int misses, LD b[2],
                       LD* log_scale) {
  const LD p_occ = sensor.pHitGivenOcc();
  const LD p_free = sensor.pHitGivenFree();
  const LD log_occ = hits * std::log(p_occ) + misses * std::log(1.0L - p_occ);
  const LD log_free = hits * std::log(p_free) + misses * std::log(1.0L - p_free);
  *log_scale = std::max(log_occ, log_free);
  b[0] = std::exp(log_occ - *log_scale);
  b[1] = std::exp(log_free - *log_scale);
}

struct ReferenceResult {
  LD counts[2][2] = {{0.0L, 0.0L}, {0.0L, 0.0L}};
  LD log_likelihood = 0.0L;
  LD final_p_occ = 0.0L;
  std::int64_t transitions = 0;
};

// Steps t_1 - 1 .. t_n with t_n - t_1 + 1 transitions, each with its own (possibly unit)
// likelihood: alpha_k = (alpha_{k-1} A) o b_k / c_k, beta_{k-1} = A (b_k o beta_k) / c_k,
// xi_k(i, j) = alpha_{k-1}(i) A_ij b_k(j) beta_k(j) / c_k.
ReferenceResult referenceForwardBackward(const Sequence& sequence,
                                         const dog::ObservationModel& sensor,
                                         const dog::TransitionParams& transition,
                                         double initial_p_occ) {
  const Matrix2 A = transitionMatrix(transition);
  const std::int64_t first = sequence.front().step;
  const std::int64_t transitions = static_cast<std::int64_t>(sequence.back().step) - first + 1;
  std::vector<LD> alpha(2 * static_cast<std::size_t>(transitions + 1));
  std::vector<LD> b(2 * static_cast<std::size_t>(transitions + 1), 1.0L);
  std::vector<LD> c(static_cast<std::size_t>(transitions + 1));
  ReferenceResult result;
  result.transitions = transitions;
  for (const auto& z : sequence) {
    const std::size_t k = static_cast<std::size_t>(z.step - first + 1);
    LD log_scale = 0.0L;
    scaledLikelihoods(sensor, z.hits, z.misses, &b[2 * k], &log_scale);
    result.log_likelihood += log_scale;
  }
  alpha[0] = initial_p_occ;
  alpha[1] = 1.0L - static_cast<LD>(initial_p_occ);
  // log prod c_k, kept as mantissa * 2^exponent: one log at the end instead of one per step.
  LD c_mantissa = 1.0L;
  long c_exponent = 0;
  for (std::size_t k = 1; k <= static_cast<std::size_t>(transitions); ++k) {
    LD u[2];
    for (int j = 0; j < 2; ++j) {
      u[j] = (alpha[2 * (k - 1)] * A.a[0][j] + alpha[2 * (k - 1) + 1] * A.a[1][j]) * b[2 * k + j];
    }
    c[k] = u[0] + u[1];
    alpha[2 * k] = u[0] / c[k];
    alpha[2 * k + 1] = u[1] / c[k];
    int exponent = 0;
    c_mantissa = std::frexp(c_mantissa * c[k], &exponent);
    c_exponent += exponent;
  }
  result.log_likelihood += std::log(c_mantissa) + c_exponent * std::log(2.0L);
  LD beta[2] = {1.0L, 1.0L};
  for (std::size_t k = static_cast<std::size_t>(transitions); k >= 1; --k) {
    LD previous_beta[2] = {0.0L, 0.0L};
    for (int i = 0; i < 2; ++i) {
      for (int j = 0; j < 2; ++j) {
        const LD forward_backward = A.a[i][j] * b[2 * k + j] * beta[j] / c[k];
        result.counts[i][j] += alpha[2 * (k - 1) + i] * forward_backward;
        previous_beta[i] += forward_backward;
      }
    }
    beta[0] = previous_beta[0];
    beta[1] = previous_beta[1];
  }
  result.final_p_occ = alpha[2 * static_cast<std::size_t>(transitions)];
  return result;
}

// ---- independent reference: M-step, objective and EM loop from the header's promises ---

LD clampTo(LD value, double low, double high) {
  return std::min<LD>(std::max<LD>(value, low), high);
}

// Row-normalised counts plus prior_weight pseudo-transitions per from-state split as the
// prior's row; symmetric: one p_c from all changes over all transitions (the maximiser of the
// objective below with p_of = p_fo). A from-state without weight keeps `previous`.
dog::TransitionParams referenceMStep(const LD counts[2][2], const dog::OfflineEmConfig& config,
                                     const dog::TransitionParams& previous) {
  const LD w = config.prior_weight;
  const Matrix2 prior = transitionMatrix(config.prior);
  dog::TransitionParams next = previous;
  if (config.symmetric) {
    const LD total = counts[0][0] + counts[0][1] + counts[1][0] + counts[1][1] + 2.0L * w;
    if (total > 0.0L) {
      const LD changes = counts[0][1] + counts[1][0] + w * (prior.a[0][1] + prior.a[1][0]);
      const double p_c = static_cast<double>(clampTo(changes / total, config.p_min, config.p_max));
      next = params(p_c, p_c);
    }
    return next;
  }
  const LD from_occ = counts[0][0] + counts[0][1] + w;
  const LD from_free = counts[1][0] + counts[1][1] + w;
  if (from_occ > 0.0L) {
    next.p_free_given_occ = static_cast<double>(
        clampTo((counts[0][1] + w * prior.a[0][1]) / from_occ, config.p_min, config.p_max));
  }
  if (from_free > 0.0L) {
    next.p_occ_given_free = static_cast<double>(
        clampTo((counts[1][0] + w * prior.a[1][0]) / from_free, config.p_min, config.p_max));
  }
  return next;
}

// log-likelihood + sum_ij w prior_ij log a_ij (0 log 0 = 0).
LD referenceObjective(LD log_likelihood, const dog::TransitionParams& transition,
                      const dog::OfflineEmConfig& config) {
  if (config.prior_weight <= 0.0) return log_likelihood;
  const Matrix2 A = transitionMatrix(transition);
  const Matrix2 prior = transitionMatrix(config.prior);
  LD log_prior = 0.0L;
  for (int i = 0; i < 2; ++i) {
    for (int j = 0; j < 2; ++j) {
      if (prior.a[i][j] > 0.0L) {
        log_prior += config.prior_weight * prior.a[i][j] * std::log(A.a[i][j]);
      }
    }
  }
  return log_likelihood + log_prior;
}

struct ReferenceIteration {
  dog::TransitionParams params;
  LD objective;
  LD final_p_occ;
};

struct ReferenceEm {
  std::vector<ReferenceIteration> history;  ///< entry k after k M-steps
  bool converged = false;
  int iterations() const { return static_cast<int>(history.size()) - 1; }
};

// E-step, M-step, E-step ... ; stops when an M-step gains less than `tolerance` or after
// max_iterations M-steps, keeping the last M-step's parameters. EM never loses objective, so
// with tolerance 0 a gain could fall below it only by rounding: tolerance 0 runs
// max_iterations.
ReferenceEm referenceEm(const Sequence& sequence, const dog::ObservationModel& sensor,
                        const dog::OfflineEmConfig& config) {
  ReferenceEm em;
  dog::TransitionParams current = config.initial_params;
  ReferenceResult e_step =
      referenceForwardBackward(sequence, sensor, current, config.initial_p_occ);
  em.history.push_back(ReferenceIteration{
      current, referenceObjective(e_step.log_likelihood, current, config), e_step.final_p_occ});
  while (em.iterations() < config.max_iterations) {
    current = referenceMStep(e_step.counts, config, current);
    e_step = referenceForwardBackward(sequence, sensor, current, config.initial_p_occ);
    em.history.push_back(ReferenceIteration{
        current, referenceObjective(e_step.log_likelihood, current, config), e_step.final_p_occ});
    const LD gain = em.history.back().objective - em.history[em.history.size() - 2].objective;
    if (config.tolerance > 0.0 && gain < config.tolerance) {
      em.converged = true;
      break;
    }
  }
  return em;
}

// The summed objective of OfflineEmResult: entry k over cells, a stopped cell repeating its
// last value.
LD referenceObjectiveSum(const std::vector<ReferenceEm>& cells, std::size_t k) {
  LD sum = 0.0L;
  for (const auto& cell : cells) {
    sum += cell.history[std::min(k, cell.history.size() - 1)].objective;
  }
  return sum;
}

// ---- random inputs ---------------------------------------------------------------------

double logUniform(std::mt19937_64& rng, double low, double high) {
  std::uniform_real_distribution<double> u(std::log(low), std::log(high));
  return std::exp(u(rng));
}

// Transition parameters over the whole valid square, weighted towards the edge cases the
// closed forms must treat separately.
dog::TransitionParams randomParams(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  switch (std::uniform_int_distribution<int>(0, 11)(rng)) {
    case 0:  // anywhere: lambda of either sign
      return params(unit(rng), unit(rng));
    case 1: {  // slow cells, where rates live
      return params(logUniform(rng, 1e-6, 0.2), logUniform(rng, 1e-6, 0.2));
    }
    case 2:  // static cell, A = I
      return params(0.0, 0.0);
    case 3: {  // lambda = 0 exactly (dyadic values add exactly)
      const double p = std::uniform_int_distribution<int>(1, 1023)(rng) / 1024.0;
      return params(p, 1.0 - p);
    }
    case 4: {  // lambda within rounding of 0
      const double p = unit(rng);
      return params(p, 1.0 - p);
    }
    case 5:  // lambda = -1: a deterministic oscillation
      return params(1.0, 1.0);
    case 6:  // tiny sums: lambda within 1e-9 of 1
      return params(1e-9 * unit(rng), 1e-9 * unit(rng));
    case 7: {  // one of them 0
      const double p = unit(rng) < 0.5 ? unit(rng) : logUniform(rng, 1e-9, 0.1);
      return unit(rng) < 0.5 ? params(p, 0.0) : params(0.0, p);
    }
    case 8:  // lambda close to -1 (offline_em.h: within 1e-6 of -1, long runs lose precision)
      return params(1.0 - 1e-3 * unit(rng), 1.0 - 1e-3 * unit(rng));
    case 9:  // lambda < 0
      return params(0.5 + 0.5 * unit(rng), 0.5 + 0.5 * unit(rng));
    case 10: {  // p_of = p_fo
      const double p = unit(rng);
      return params(p, p);
    }
    default: {  // one of them 1
      const double p = unit(rng);
      return unit(rng) < 0.5 ? params(p, 1.0) : params(1.0, p);
    }
  }
}

dog::ObservationModel randomSensor(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const double p_hit_occ = 0.55 + 0.43 * unit(rng);
  const double p_hit_free = 0.01 + (p_hit_occ - 0.02) * unit(rng);
  return dog::ObservationModel(p_hit_occ, p_hit_free);
}

double randomInitialPOcc(std::mt19937_64& rng) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  if (unit(rng) < 0.2) return 0.5;
  if (unit(rng) < 0.2) return unit(rng) < 0.5 ? 1e-6 : 1.0 - 1e-6;
  return 0.01 + 0.98 * unit(rng);
}

// Observed steps with gaps log-uniform in [1, max_gap] (one gap in ten exactly 1), each
// with 0..max_count hits and misses; the sequence stops growing at `max_span` transitions.
Sequence randomSequence(std::mt19937_64& rng, int max_observations, double max_gap,
                        std::int64_t max_span, int max_count) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_int_distribution<int> count(0, max_count);
  const int n = std::uniform_int_distribution<int>(1, max_observations)(rng);
  std::int64_t step = std::uniform_int_distribution<std::int64_t>(-1000000, 1000000)(rng);
  const std::int64_t first = step;
  Sequence sequence;
  for (int i = 0; i < n; ++i) {
    if (i > 0) {
      const std::int64_t gap =
          unit(rng) < 0.1 ? 1
                          : std::max<std::int64_t>(1, std::llround(logUniform(rng, 1.0, max_gap)));
      if (step + gap - first + 1 > max_span) break;
      step += gap;
    }
    sequence.push_back(observation(static_cast<std::int32_t>(step), count(rng), count(rng)));
  }
  return sequence;
}

std::string describe(const Sequence& sequence, const dog::ObservationModel& sensor,
                     const dog::TransitionParams& transition, double initial_p_occ) {
  std::ostringstream out;
  out.precision(17);
  out << "sensor(" << sensor.pHitGivenOcc() << ", " << sensor.pHitGivenFree()
      << ") p_of=" << transition.p_occ_given_free << " p_fo=" << transition.p_free_given_occ
      << " initial_p_occ=" << initial_p_occ << " observations(step,hits,misses):";
  for (std::size_t i = 0; i < sequence.size() && i < 12; ++i) {
    out << " (" << sequence[i].step << "," << sequence[i].hits << "," << sequence[i].misses << ")";
  }
  if (sequence.size() > 12) out << " ... " << sequence.size() << " in all";
  return out.str();
}

dog::ForwardBackwardResult forwardBackward(const Sequence& sequence,
                                           const dog::ObservationModel& sensor,
                                           const dog::TransitionParams& transition,
                                           double initial_p_occ) {
  return dog::forwardBackward(sequence.data(), sequence.data() + sequence.size(), sensor,
                              transition, initial_p_occ);
}

// One cell per sequence, at (index, -index) so that negative coordinates are exercised.
dog::ObservationSequences buildSequences(const std::vector<Sequence>& cells) {
  dog::SequenceBuilder builder;
  for (std::size_t i = 0; i < cells.size(); ++i) {
    for (const auto& z : cells[i]) {
      const auto index = static_cast<std::int32_t>(i);
      builder.add(index, -index, z.step, z.hits, z.misses);
    }
  }
  return builder.build();
}

// A cell simulated from the model: the state starts from pi (from 0.5 for a static cell),
// each step is observed with probability p_observed by 1..max_beams beams.
Sequence simulateCell(std::mt19937_64& rng, const dog::TransitionParams& truth,
                      const dog::ObservationModel& sensor, int steps, double p_observed,
                      int max_beams) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const double sum = truth.p_occ_given_free + truth.p_free_given_occ;
  bool occupied = unit(rng) < (sum > 0.0 ? truth.p_occ_given_free / sum : 0.5);
  Sequence sequence;
  for (int step = 0; step < steps; ++step) {
    occupied = occupied ? unit(rng) >= truth.p_free_given_occ : unit(rng) < truth.p_occ_given_free;
    if (unit(rng) >= p_observed) continue;
    const int beams = std::uniform_int_distribution<int>(1, max_beams)(rng);
    const double p_hit = occupied ? sensor.pHitGivenOcc() : sensor.pHitGivenFree();
    int hits = 0;
    for (int beam = 0; beam < beams; ++beam) hits += unit(rng) < p_hit ? 1 : 0;
    sequence.push_back(observation(step, hits, beams - hits));
  }
  if (sequence.empty()) sequence.push_back(observation(steps, 0, 1));
  return sequence;
}

// Cells for the EM tests: varied truths and observation rates; one cell in ten is observed
// in only a few steps.
std::vector<Sequence> simulatedCells(std::mt19937_64& rng, const dog::ObservationModel& sensor,
                                     int count, int steps) {
  std::vector<Sequence> cells;
  for (int i = 0; i < count; ++i) {
    const auto truth = params(logUniform(rng, 0.003, 0.3), logUniform(rng, 0.003, 0.3));
    const double p_observed = i % 10 == 9 ? 0.002 : logUniform(rng, 0.05, 0.9);
    cells.push_back(simulateCell(rng, truth, sensor, steps, p_observed, 3));
  }
  return cells;
}

std::uint64_t bits(double value) {
  std::uint64_t result = 0;
  std::memcpy(&result, &value, sizeof(result));
  return result;
}

// |actual - expected| <= rel_tol * max(|expected|, floor).
bool near(double actual, LD expected, double rel_tol, LD floor) {
  return std::isfinite(actual) && std::fabs(static_cast<LD>(actual) - expected) <=
                                      rel_tol * std::max(std::fabs(expected), floor);
}

// Collects comparisons over a sweep and reports the count of failures plus the first one
// with its inputs, instead of thousands of lines.
class SweepCheck {
 public:
  void check(bool ok, double actual, LD expected, const std::string& what,
             const std::string& inputs) {
    ++checked_;
    if (ok) return;
    if (failures_++ == 0) {
      std::ostringstream out;
      out.precision(17);
      out << what << ": actual " << actual << " expected " << static_cast<double>(expected)
          << " for " << inputs;
      first_failure_ = out.str();
    }
  }
  void expectNoFailure() const {
    EXPECT_EQ(failures_, 0u) << "of " << checked_ << " checks; first: " << first_failure_;
  }

 private:
  std::size_t checked_ = 0;
  std::size_t failures_ = 0;
  std::string first_failure_;
};

void compareWithReference(const dog::ForwardBackwardResult& actual, const ReferenceResult& expected,
                          double rel_tol, const std::string& inputs, SweepCheck* sweep) {
  const char* names[2][2] = {{"counts occ->occ", "counts occ->free"},
                             {"counts free->occ", "counts free->free"}};
  for (int i = 0; i < 2; ++i) {
    for (int j = 0; j < 2; ++j) {
      // The closed forms add terms as large as a run's length, so a count is good to
      // rounding times the number of transitions; relative accuracy is asked of counts above
      // 1e-3 of the transitions, 1e-12 of them absolutely below (an off-by-one run or a
      // swapped index is off by a whole transition).
      sweep->check(
          near(actual.counts[i][j], expected.counts[i][j], rel_tol, 1e-3L * expected.transitions),
          actual.counts[i][j], expected.counts[i][j], names[i][j], inputs);
    }
  }
  // Near 0 nats (steps without evidence only) rel_tol nats absolutely.
  sweep->check(near(actual.log_likelihood, expected.log_likelihood, rel_tol, 1.0L),
               actual.log_likelihood, expected.log_likelihood, "log_likelihood", inputs);
  // A probability is good to rounding absolutely (1e-15) and rel_tol relatively above 1e-6.
  sweep->check(near(actual.final_p_occ, expected.final_p_occ, rel_tol, 1e-6L), actual.final_p_occ,
               expected.final_p_occ, "final_p_occ", inputs);
}

}  // namespace

// =====================================================================================
// 1. forwardBackward == plain forward–backward over the expanded sequence.
// =====================================================================================

TEST(OfflineEmForwardBackward, MatchesExpandedReferenceOverRandomCells) {
  std::mt19937_64 rng(20240917);
  SweepCheck sweep;
  for (int trial = 0; trial < 3000; ++trial) {
    const auto sensor = randomSensor(rng);
    const auto transition = randomParams(rng);
    const double initial_p_occ = randomInitialPOcc(rng);
    // One sequence in five with gaps up to 1e4 steps; the others shorter, to bound the
    // reference's work.
    const double max_gap = trial % 5 == 0 ? 1e4 : 300.0;
    const Sequence sequence = randomSequence(rng, 25, max_gap, 15000, 5);
    const auto expected = referenceForwardBackward(sequence, sensor, transition, initial_p_occ);
    const auto actual = forwardBackward(sequence, sensor, transition, initial_p_occ);
    compareWithReference(actual, expected, 1e-9,
                         describe(sequence, sensor, transition, initial_p_occ), &sweep);
  }
  sweep.expectNoFailure();
}

TEST(OfflineEmForwardBackward, ManyBeamsPerStepDoNotOverflow) {
  // Steps with 200 fused beams: likelihoods down to 0.3^200 ~ 1e-105 and products of them
  // far below the smallest double. Mixing cells (p >= 1e-4) keep every predicted belief
  // away from certainty, so the result is well defined in double.
  std::mt19937_64 rng(200);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const dog::ObservationModel sensor(0.7, 0.3);
  SweepCheck sweep;
  for (int trial = 0; trial < 300; ++trial) {
    const auto transition = params(logUniform(rng, 1e-4, 0.9), logUniform(rng, 1e-4, 0.9));
    Sequence sequence = randomSequence(rng, 25, 1e3, 10000, 5);
    for (auto& z : sequence) {
      if (unit(rng) < 0.5) z.hits = 200;
      if (unit(rng) < 0.3) z.misses = 200;
    }
    const auto expected = referenceForwardBackward(sequence, sensor, transition, 0.5);
    const auto actual = forwardBackward(sequence, sensor, transition, 0.5);
    compareWithReference(actual, expected, 1e-9, describe(sequence, sensor, transition, 0.5),
                         &sweep);
  }
  sweep.expectNoFailure();
}

// A small belief must keep its relative precision across a gap: p(occ) ~ 3e-14 after the
// first step, which the second step's evidence brings back to exactly 0.5. By the sensor's
// symmetry (p(hit|occ) = p(miss|free) = 0.98) the two steps' evidence cancels, so by hand:
// p(occ at t_n) = 0.5, p(z) = 0.5 (0.02^8 0.98^8) + 0.5 (0.98^8 0.02^8) = 0.0196^8, and each
// of the 3 transitions is occ->occ or free->free (static), or a change (p_of = p_fo = 1),
// with probability 0.5.
TEST(OfflineEmForwardBackward, SmallBeliefsKeepTheirPrecisionAcrossAGap) {
  const dog::ObservationModel sensor(0.98, 0.02);
  const Sequence sequence = {observation(0, 0, 8), observation(2, 8, 0)};
  const double expected_log_likelihood = 8.0 * std::log(0.0196);
  for (const bool oscillating : {false, true}) {
    const auto transition = oscillating ? params(1.0, 1.0) : params(0.0, 0.0);
    SCOPED_TRACE(describe(sequence, sensor, transition, 0.5));
    const auto actual = forwardBackward(sequence, sensor, transition, 0.5);
    EXPECT_NEAR(actual.final_p_occ, 0.5, 1e-12);
    EXPECT_NEAR(actual.log_likelihood, expected_log_likelihood, 1e-12);
    EXPECT_NEAR(actual.counts[0][oscillating ? 1 : 0], 1.5, 1e-12);
    EXPECT_NEAR(actual.counts[1][oscillating ? 0 : 1], 1.5, 1e-12);
    EXPECT_NEAR(actual.counts[0][oscillating ? 0 : 1], 0.0, 1e-12);
    EXPECT_NEAR(actual.counts[1][oscillating ? 1 : 0], 0.0, 1e-12);
  }
}

// Beliefs closer to certainty than double resolves near 1 (here 1 - p(occ) ~ 1e-22) must not
// become certain: later evidence against them has to be able to overturn them, as it does
// in the model. Cells whose transitions cannot pull the belief back (static, absorbing,
// deterministic) show it; one strong step, then stronger evidence the other way (in the
// second case so strong that p(z|occ) / p(z|free) ~ 1e-382 underflows).
TEST(OfflineEmForwardBackward, NearCertainBeliefsStayReversible) {
  const std::vector<std::pair<dog::ObservationModel, Sequence>> cases = {
      {dog::ObservationModel(0.7, 0.3), {observation(0, 60, 0), observation(2, 0, 120)}},
      {dog::ObservationModel(0.9, 0.1), {observation(0, 60, 0), observation(1, 0, 400)}}};
  for (const auto& [sensor, sequence] : cases) {
    for (const auto& transition : {params(0.0, 0.0), params(0.1, 0.0), params(1.0, 1.0)}) {
      const std::string inputs = describe(sequence, sensor, transition, 0.5);
      SCOPED_TRACE(inputs);
      const auto expected = referenceForwardBackward(sequence, sensor, transition, 0.5);
      const auto actual = forwardBackward(sequence, sensor, transition, 0.5);
      SweepCheck sweep;
      compareWithReference(actual, expected, 1e-9, inputs, &sweep);
      sweep.expectNoFailure();
    }
  }
  const dog::ObservationModel sensor(0.7, 0.3);
  const Sequence sequence = {observation(0, 60, 0), observation(2, 0, 120)};
  // The static cell by hand: p(z) = 0.5 b_occ + 0.5 b_free over both steps' 60 hits and
  // 120 misses; 0.7^60 0.3^120 against 0.3^60 0.7^120: log-odds 60 ln(7/3) - 120 ln(7/3).
  const auto actual = forwardBackward(sequence, sensor, params(0.0, 0.0), 0.5);
  const LD log_odds = -60.0L * std::log(7.0L / 3.0L);
  EXPECT_TRUE(near(actual.final_p_occ, 1.0L / (1.0L + std::exp(-log_odds)), 1e-9, 1e-300L))
      << actual.final_p_occ << " vs " << static_cast<double>(1.0L / (1.0L + std::exp(-log_odds)));
}

TEST(OfflineEmForwardBackward, SaturatedCountsStayFinite) {
  // 65535 hits and misses (the builder's saturation): likelihoods like 0.1^65535 are far
  // below the smallest double, so only a scaled recursion gets these right.
  std::mt19937_64 rng(5);
  const dog::ObservationModel sensor(0.8, 0.1);
  SweepCheck sweep;
  for (int trial = 0; trial < 200; ++trial) {
    const auto transition = params(logUniform(rng, 1e-6, 0.5), logUniform(rng, 1e-6, 0.5));
    Sequence sequence = randomSequence(rng, 10, 1e3, 5000, 5);
    for (std::size_t i = 0; i < sequence.size(); i += 2) {
      sequence[i].hits = trial % 2 == 0 ? 65535 : sequence[i].hits;
      sequence[i].misses = trial % 3 == 0 ? 65535 : sequence[i].misses;
    }
    const auto expected = referenceForwardBackward(sequence, sensor, transition, 0.5);
    const auto actual = forwardBackward(sequence, sensor, transition, 0.5);
    compareWithReference(actual, expected, 1e-9, describe(sequence, sensor, transition, 0.5),
                         &sweep);
  }
  sweep.expectNoFailure();
}

// =====================================================================================
// 2. Short sequences: expected counts by enumerating every state path.
// =====================================================================================

TEST(OfflineEmForwardBackward, MatchesPathEnumeration) {
  std::mt19937_64 rng(31);
  std::uniform_int_distribution<int> count(0, 5);
  SweepCheck sweep;
  for (int trial = 0; trial < 2000; ++trial) {
    // Every other trial reads steps whose beams disagree as possibly mixed (ObservationModel).
    const auto plain = randomSensor(rng);
    const double eps = trial % 2 == 0 ? 0.0 : std::uniform_real_distribution<double>(1e-4, 0.5)(rng);
    const dog::ObservationModel sensor(plain.pHitGivenOcc(), plain.pHitGivenFree(), eps);
    const auto transition = randomParams(rng);
    const double initial_p_occ = randomInitialPOcc(rng);
    // Observed steps: a random subset of t_1 .. t_1 + span - 1 holding both ends, so the
    // chain x_0 .. x_span has at most 8 transitions and 2^9 paths.
    const int span = std::uniform_int_distribution<int>(1, 8)(rng);
    const std::int32_t first = std::uniform_int_distribution<std::int32_t>(-50, 50)(rng);
    Sequence sequence;
    for (int k = 0; k < span; ++k) {
      if (k == 0 || k == span - 1 || std::uniform_int_distribution<int>(0, 1)(rng) == 1) {
        sequence.push_back(observation(first + k, count(rng), count(rng)));
      }
    }
    // b_k(s) for k = 1..span: the true (unscaled) likelihoods, 1 without observation.
    LD b[9][2];
    for (auto& row : b) row[0] = row[1] = 1.0L;
    for (const auto& z : sequence) {
      const LD p_hit[2] = {sensor.pHitGivenOcc(), sensor.pHitGivenFree()};
      // A partly covered cell's sequence likelihood, the integral of q^h (1 - q)^m:
      // h! m! / (h + m + 1)!.
      LD beta = 1.0L / (z.hits + z.misses + 1);
      for (std::uint32_t i = 1; i <= z.misses; ++i) beta *= static_cast<LD>(i) / (z.hits + i);
      const bool mixed = z.hits > 0 && z.misses > 0;
      for (int s = 0; s < 2; ++s) {
        const LD state_likelihood = std::pow(p_hit[s], static_cast<LD>(z.hits)) *
                                    std::pow(1.0L - p_hit[s], static_cast<LD>(z.misses));
        b[z.step - first + 1][s] = mixed ? (1.0L - eps) * state_likelihood + eps * beta : state_likelihood;
      }
    }
    const Matrix2 A = transitionMatrix(transition);
    LD evidence = 0.0L;
    LD weighted_counts[2][2] = {{0.0L, 0.0L}, {0.0L, 0.0L}};
    LD evidence_final_occ = 0.0L;
    // The sensor model's E-step: beam ends and hits per state, weighted by the path.
    LD weighted_trials[2] = {0.0L, 0.0L};
    LD weighted_hits[2] = {0.0L, 0.0L};
    for (unsigned path = 0; path < (1u << (span + 1)); ++path) {
      // Bit k of `path` is x_k (1 = free).
      auto state = [path](int k) { return static_cast<int>((path >> k) & 1u); };
      LD probability = state(0) == 0 ? static_cast<LD>(initial_p_occ) : 1.0L - initial_p_occ;
      int transitions[2][2] = {{0, 0}, {0, 0}};
      for (int k = 1; k <= span; ++k) {
        probability *= A.a[state(k - 1)][state(k)] * b[k][state(k)];
        ++transitions[state(k - 1)][state(k)];
      }
      evidence += probability;
      if (state(span) == 0) evidence_final_occ += probability;
      for (const auto& z : sequence) {
        const int s_k = state(z.step - first + 1);
        weighted_trials[s_k] += probability * (z.hits + z.misses);
        weighted_hits[s_k] += probability * z.hits;
      }
      for (int i = 0; i < 2; ++i) {
        for (int j = 0; j < 2; ++j) weighted_counts[i][j] += probability * transitions[i][j];
      }
    }
    const auto actual = forwardBackward(sequence, sensor, transition, initial_p_occ);
    const std::string inputs = describe(sequence, sensor, transition, initial_p_occ);
    for (int i = 0; i < 2; ++i) {
      for (int j = 0; j < 2; ++j) {
        const LD expected = weighted_counts[i][j] / evidence;
        sweep.check(near(actual.counts[i][j], expected, 1e-12, 1.0L), actual.counts[i][j], expected,
                    "counts", inputs);
      }
    }
    sweep.check(near(actual.log_likelihood, std::log(evidence), 1e-12, 1.0L), actual.log_likelihood,
                std::log(evidence), "log_likelihood", inputs);
    sweep.check(near(actual.final_p_occ, evidence_final_occ / evidence, 1e-12, 1.0L),
                actual.final_p_occ, evidence_final_occ / evidence, "final_p_occ", inputs);
    for (int s = 0; s < 2; ++s) {
      sweep.check(near(actual.expected_trials[s], weighted_trials[s] / evidence, 1e-12, 1.0L),
                  actual.expected_trials[s], weighted_trials[s] / evidence, "expected_trials", inputs);
      sweep.check(near(actual.expected_hits[s], weighted_hits[s] / evidence, 1e-12, 1.0L), actual.expected_hits[s],
                  weighted_hits[s] / evidence, "expected_hits", inputs);
    }
  }
  sweep.expectNoFailure();
}

// =====================================================================================
// 3. Counts are a distribution over the t_n - t_1 + 1 transitions, whatever the gaps.
// =====================================================================================

TEST(OfflineEmForwardBackward, CountsSumToTheNumberOfTransitions) {
  std::mt19937_64 rng(77);
  SweepCheck sweep;
  for (int trial = 0; trial < 3000; ++trial) {
    const auto sensor = randomSensor(rng);
    const auto transition = randomParams(rng);
    const double initial_p_occ = randomInitialPOcc(rng);
    // Gaps up to 1e8 steps: far beyond what a loop over steps could afford.
    const Sequence sequence = randomSequence(rng, 30, 1e8, 2000000000, 5);
    const auto actual = forwardBackward(sequence, sensor, transition, initial_p_occ);
    const std::string inputs = describe(sequence, sensor, transition, initial_p_occ);
    const LD transitions = static_cast<LD>(sequence.back().step) - sequence.front().step + 1;
    LD sum = 0.0L;
    for (const auto& row : actual.counts) {
      for (const double n : row) {
        // Non-negative up to the rounding of the closed forms (see compareWithReference).
        sweep.check(n >= -1e-12 * static_cast<double>(transitions), n, 0.0L, "count >= 0", inputs);
        sum += n;
      }
    }
    sweep.check(near(static_cast<double>(sum), transitions, 1e-9, 1.0L), static_cast<double>(sum),
                transitions, "sum of counts", inputs);
    sweep.check(std::isfinite(actual.log_likelihood) && actual.log_likelihood <= 0.0,
                actual.log_likelihood, 0.0L, "log_likelihood finite and <= 0", inputs);
    sweep.check(actual.final_p_occ >= 0.0 && actual.final_p_occ <= 1.0, actual.final_p_occ, 0.5L,
                "final_p_occ in [0, 1]", inputs);
  }
  sweep.expectNoFailure();
}

// Past a few mixing times a gap adds nothing but stationary transitions: with lambda^G = 0,
// the counts of a gap of G steps are those of a gap of G1 plus (G - G1) times the middle
// step's xi (pi_i A_ij for a mixing cell, the posterior on the diagonal for a static one),
// and the log-likelihood and final belief do not change. The reference is run with G1 and
// shifted; the code under test must cross G ~ 2e9 steps in O(1).
TEST(OfflineEmForwardBackward, HugeGapsMatchTheReferenceExtrapolated) {
  const dog::ObservationModel sensor(0.8, 0.15);
  const auto check = [&](const dog::TransitionParams& transition, std::int32_t first_step,
                         std::int32_t last_step) {
    SCOPED_TRACE(::testing::Message() << "p_of=" << transition.p_occ_given_free
                                      << " p_fo=" << transition.p_free_given_occ << " steps "
                                      << first_step << " .. " << last_step);
    // Three observations at each end, the middle gap `gap` steps long.
    const std::int64_t short_gap = 20000;
    const auto make = [&](std::int64_t gap) {
      const auto at = [&](std::int64_t offset) {
        return static_cast<std::int32_t>(first_step + offset);
      };
      return Sequence{observation(at(0), 2, 0),       observation(at(1), 0, 1),
                      observation(at(2), 1, 1),       observation(at(2 + gap), 0, 2),
                      observation(at(3 + gap), 3, 0), observation(at(4 + gap), 0, 0)};
    };
    const std::int64_t long_gap = static_cast<std::int64_t>(last_step) - first_step - 4;
    const Sequence long_sequence = make(long_gap);
    ASSERT_EQ(long_sequence.back().step, last_step);
    const Sequence short_sequence = make(short_gap);
    const auto reference = referenceForwardBackward(short_sequence, sensor, transition, 0.3);
    const auto actual = forwardBackward(long_sequence, sensor, transition, 0.3);

    const Matrix2 A = transitionMatrix(transition);
    LD middle[2][2];
    if (transition.isStatic()) {
      middle[0][0] = reference.final_p_occ;
      middle[1][1] = 1.0L - reference.final_p_occ;
      middle[0][1] = middle[1][0] = 0.0L;
    } else {
      const LD pi_occ =
          static_cast<LD>(transition.p_occ_given_free) /
          (static_cast<LD>(transition.p_occ_given_free) + transition.p_free_given_occ);
      const LD pi[2] = {pi_occ, 1.0L - pi_occ};
      for (int i = 0; i < 2; ++i) {
        for (int j = 0; j < 2; ++j) middle[i][j] = pi[i] * A.a[i][j];
      }
    }
    const LD extra = static_cast<LD>(long_gap - short_gap);
    LD sum = 0.0L;
    for (int i = 0; i < 2; ++i) {
      for (int j = 0; j < 2; ++j) {
        const LD expected = reference.counts[i][j] + extra * middle[i][j];
        EXPECT_TRUE(near(actual.counts[i][j], expected, 1e-9, 1.0L))
            << "counts[" << i << "][" << j << "] = " << actual.counts[i][j] << ", expected "
            << static_cast<double>(expected);
        sum += actual.counts[i][j];
      }
    }
    const LD transitions = static_cast<LD>(last_step) - first_step + 1;
    EXPECT_TRUE(near(static_cast<double>(sum), transitions, 1e-9, 1.0L))
        << static_cast<double>(sum) << " vs " << static_cast<double>(transitions);
    EXPECT_TRUE(near(actual.log_likelihood, reference.log_likelihood, 1e-9, 1.0L))
        << actual.log_likelihood << " vs " << static_cast<double>(reference.log_likelihood);
    EXPECT_TRUE(near(actual.final_p_occ, reference.final_p_occ, 1e-9, 1e-300L))
        << actual.final_p_occ << " vs " << static_cast<double>(reference.final_p_occ);
  };
  const std::int32_t kMax = std::numeric_limits<std::int32_t>::max();
  const std::int32_t kMin = std::numeric_limits<std::int32_t>::min();
  check(params(0.01, 0.02), 0, 2000000000);
  check(params(0.7, 0.6), -1000000000, 1000000000);  // lambda < 0
  check(params(0.0, 0.0), 0, 2000000000);            // static: the posterior, 2e9 times
  check(params(0.2, 0.0), 5, 2000000005);            // absorbing in occ
  // Nearly the whole int32 range: 2^32 - 1 transitions, more than 32 bits can count.
  check(params(0.01, 0.02), kMin + 1, kMax);
  check(params(0.01, 0.02), 0, kMax);
}

// =====================================================================================
// 4. The M-step and the EM loop against the reference.
// =====================================================================================

namespace {

// The EM configurations under test, all with tolerance 0 so every cell runs every
// iteration: maximum likelihood, MAP, symmetric (plain and MAP from asymmetric initial
// parameters), and bounds that bind (initial parameters outside them).
std::vector<std::pair<std::string, dog::OfflineEmConfig>> emConfigs() {
  dog::OfflineEmConfig ml;
  ml.initial_p_occ = 0.3;
  ml.tolerance = 0.0;
  ml.threads = 2;
  dog::OfflineEmConfig map = ml;
  map.prior_weight = 5.0;
  map.prior = params(0.02, 0.01);
  dog::OfflineEmConfig symmetric = ml;
  symmetric.symmetric = true;
  dog::OfflineEmConfig symmetric_map = map;
  symmetric_map.symmetric = true;
  symmetric_map.initial_params = params(0.2, 0.01);
  dog::OfflineEmConfig bounded = ml;
  bounded.p_min = 0.02;
  bounded.p_max = 0.06;
  bounded.initial_params = params(0.3, 0.001);
  return {{"maximum likelihood", ml},
          {"MAP", map},
          {"symmetric", symmetric},
          {"symmetric MAP", symmetric_map},
          {"bounds active", bounded}};
}

dog::TransitionCounts toCounts(const LD counts[2][2]) {
  dog::TransitionCounts result{};
  for (int i = 0; i < 2; ++i) {
    for (int j = 0; j < 2; ++j) result[i][j] = static_cast<double>(counts[i][j]);
  }
  return result;
}

}  // namespace

TEST(OfflineEmMStep, MatchesReferenceMStep) {
  std::mt19937_64 rng(404);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  SweepCheck sweep;
  for (int trial = 0; trial < 5000; ++trial) {
    dog::OfflineEmConfig config;
    config.prior = randomParams(rng);
    config.prior_weight = std::vector<double>{0.0, 0.5, 5.0, 1000.0}[trial % 4];
    config.symmetric = trial % 3 == 0;
    config.p_min = unit(rng) < 0.5 ? 0.0 : 0.1 * unit(rng);
    config.p_max = config.p_min + (1.0 - config.p_min) * unit(rng);
    // Counts of all magnitudes, a row or all of them empty now and then.
    LD counts[2][2];
    for (auto& row : counts) {
      for (auto& n : row) n = unit(rng) < 0.1 ? 0.0 : logUniform(rng, 1e-6, 1e6);
    }
    if (trial % 7 == 0) counts[0][0] = counts[0][1] = 0.0L;
    if (trial % 11 == 0) counts[1][0] = counts[1][1] = 0.0L;
    const auto previous = randomParams(rng);
    const auto expected = referenceMStep(counts, config, previous);
    const auto actual = dog::offlineMStep(toCounts(counts), config, previous);
    std::ostringstream inputs;
    inputs.precision(17);
    inputs << "counts " << static_cast<double>(counts[0][0]) << " "
           << static_cast<double>(counts[0][1]) << " " << static_cast<double>(counts[1][0]) << " "
           << static_cast<double>(counts[1][1]) << " w=" << config.prior_weight
           << " symmetric=" << config.symmetric << " bounds " << config.p_min << ".."
           << config.p_max;
    sweep.check(near(actual.p_occ_given_free, expected.p_occ_given_free, 1e-12, 1e-300L),
                actual.p_occ_given_free, expected.p_occ_given_free, "p_of", inputs.str());
    sweep.check(near(actual.p_free_given_occ, expected.p_free_given_occ, 1e-12, 1e-300L),
                actual.p_free_given_occ, expected.p_free_given_occ, "p_fo", inputs.str());
  }
  sweep.expectNoFailure();
}

TEST(OfflineEmMStep, FromStateWithoutWeightKeepsPrevious) {
  dog::OfflineEmConfig config;             // prior_weight 0
  const auto previous = params(0.3, 0.7);  // outside the bounds: kept as it is
  const dog::TransitionCounts only_from_occ{{{90.0, 10.0}, {0.0, 0.0}}};
  const auto next = dog::offlineMStep(only_from_occ, config, previous);
  EXPECT_EQ(next.p_occ_given_free, 0.3);
  EXPECT_DOUBLE_EQ(next.p_free_given_occ, 0.1);
  const dog::TransitionCounts only_from_free{{{0.0, 0.0}, {1.0, 3.0}}};
  const auto other = dog::offlineMStep(only_from_free, config, previous);
  EXPECT_DOUBLE_EQ(other.p_occ_given_free, 0.25);
  EXPECT_EQ(other.p_free_given_occ, 0.7);
  config.symmetric = true;
  const auto kept = dog::offlineMStep(dog::TransitionCounts{}, config, previous);
  EXPECT_EQ(kept.p_occ_given_free, 0.3);
  EXPECT_EQ(kept.p_free_given_occ, 0.7);
}

TEST(OfflineEmRun, MatchesReferenceEmLoop) {
  const dog::ObservationModel sensor(0.8, 0.1);
  std::mt19937_64 rng(2718);
  const std::vector<Sequence> cells = simulatedCells(rng, sensor, 20, 1500);
  const dog::ObservationSequences sequences = buildSequences(cells);
  for (auto [name, config] : emConfigs()) {
    SCOPED_TRACE(name);
    config.max_iterations = 50;
    std::vector<ReferenceEm> reference;
    for (const auto& cell : cells) reference.push_back(referenceEm(cell, sensor, config));
    // With tolerance 0 the first 10 iterations of the 50-iteration reference are the
    // 10-iteration run.
    for (const int iterations : {10, 50}) {
      SCOPED_TRACE(iterations);
      config.max_iterations = iterations;
      const auto result = dog::runOfflineEm(sequences, sensor, config);
      ASSERT_EQ(result.params.size(), cells.size());
      ASSERT_EQ(result.objective.size(), static_cast<std::size_t>(iterations) + 1);
      EXPECT_FALSE(result.cancelled);
      EXPECT_EQ(result.cells_converged, 0u);
      SweepCheck sweep;
      for (std::size_t k = 0; k <= static_cast<std::size_t>(iterations); ++k) {
        const LD expected = referenceObjectiveSum(reference, k);
        sweep.check(near(result.objective[k], expected, 1e-9, 1.0L), result.objective[k], expected,
                    "objective[" + std::to_string(k) + "]", name);
      }
      for (std::size_t c = 0; c < cells.size(); ++c) {
        const ReferenceIteration& expected = reference[c].history[iterations];
        const std::string inputs = "cell " + std::to_string(c) + " (" + name + ")";
        EXPECT_EQ(result.iterations[c], iterations) << inputs;
        sweep.check(near(result.params[c].p_occ_given_free, expected.params.p_occ_given_free, 1e-9,
                         1e-300L),
                    result.params[c].p_occ_given_free, expected.params.p_occ_given_free, "p_of",
                    inputs);
        sweep.check(near(result.params[c].p_free_given_occ, expected.params.p_free_given_occ, 1e-9,
                         1e-300L),
                    result.params[c].p_free_given_occ, expected.params.p_free_given_occ, "p_fo",
                    inputs);
        sweep.check(near(result.final_p_occ[c], expected.final_p_occ, 1e-9, 1e-300L),
                    result.final_p_occ[c], expected.final_p_occ, "final_p_occ", inputs);
      }
      sweep.expectNoFailure();
    }
  }
}

TEST(OfflineEmRun, StopsWhenTheGainFallsBelowTheTolerance) {
  const dog::ObservationModel sensor(0.8, 0.1);
  std::mt19937_64 rng(1618);
  std::vector<Sequence> cells = simulatedCells(rng, sensor, 60, 1500);
  dog::OfflineEmConfig config;
  config.tolerance = 1e-3;
  config.max_iterations = 40;
  config.prior_weight = 1.0;
  std::vector<ReferenceEm> reference;
  for (const auto& cell : cells) reference.push_back(referenceEm(cell, sensor, config));
  // Cells that stop first come first, so that every later cell lengthens the summed
  // objective and the stopped ones must be carried forward with their last value.
  std::vector<std::size_t> order(cells.size());
  for (std::size_t c = 0; c < order.size(); ++c) order[c] = c;
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    return reference[a].iterations() < reference[b].iterations();
  });
  std::vector<Sequence> sorted_cells;
  std::vector<ReferenceEm> sorted_reference;
  for (const std::size_t c : order) {
    sorted_cells.push_back(cells[c]);
    sorted_reference.push_back(reference[c]);
  }
  cells.swap(sorted_cells);
  reference.swap(sorted_reference);
  std::size_t converged = 0;
  for (const auto& em : reference) {
    converged += em.converged ? 1 : 0;
    // A gain within rounding of the tolerance would make the expected stop ambiguous.
    for (std::size_t k = 1; k < em.history.size(); ++k) {
      ASSERT_GT(std::fabs(em.history[k].objective - em.history[k - 1].objective - config.tolerance),
                1e-7L);
    }
  }
  // The data must exercise both ways of stopping, and several stopping iterations.
  ASSERT_GT(converged, 0u);
  ASSERT_LT(converged, cells.size());
  ASSERT_LT(reference.front().iterations(), reference.back().iterations());

  const auto result = dog::runOfflineEm(buildSequences(cells), sensor, config);
  EXPECT_EQ(result.cells_converged, converged);
  std::size_t longest = 0;
  SweepCheck sweep;
  for (std::size_t c = 0; c < cells.size(); ++c) {
    const ReferenceEm& expected = reference[c];
    longest = std::max(longest, expected.history.size());
    const std::string inputs = "cell " + std::to_string(c);
    EXPECT_EQ(result.iterations[c], expected.iterations()) << inputs;
    sweep.check(near(result.params[c].p_occ_given_free,
                     expected.history.back().params.p_occ_given_free, 1e-9, 1e-300L),
                result.params[c].p_occ_given_free, expected.history.back().params.p_occ_given_free,
                "p_of", inputs);
    sweep.check(near(result.params[c].p_free_given_occ,
                     expected.history.back().params.p_free_given_occ, 1e-9, 1e-300L),
                result.params[c].p_free_given_occ, expected.history.back().params.p_free_given_occ,
                "p_fo", inputs);
  }
  ASSERT_EQ(result.objective.size(), longest);
  for (std::size_t k = 0; k < longest; ++k) {
    const LD expected = referenceObjectiveSum(reference, k);
    sweep.check(near(result.objective[k], expected, 1e-9, 1.0L), result.objective[k], expected,
                "objective[" + std::to_string(k) + "]", "sum over cells");
  }
  sweep.expectNoFailure();
}

// =====================================================================================
// 5. The result does not depend on the number of threads, to the bit.
// =====================================================================================

TEST(OfflineEmRun, ThreadCountDoesNotChangeTheResult) {
  const dog::ObservationModel sensor(0.75, 0.15);
  std::mt19937_64 rng(99);
  std::vector<Sequence> cells;
  for (int i = 0; i < 5000; ++i) {
    const auto truth = params(logUniform(rng, 0.005, 0.3), logUniform(rng, 0.005, 0.3));
    cells.push_back(i % 5 == 0 ? randomSequence(rng, 40, 1e4, 1000000, 3)
                               : simulateCell(rng, truth, sensor, 200, 0.3, 3));
  }
  const dog::ObservationSequences sequences = buildSequences(cells);
  dog::OfflineEmConfig config;
  config.max_iterations = 15;
  config.tolerance = 1e-6;  // cells stop at different iterations
  config.prior_weight = 2.0;
  config.threads = 1;
  const auto serial = dog::runOfflineEm(sequences, sensor, config);
  ASSERT_EQ(serial.params.size(), cells.size());
  ASSERT_GT(serial.cells_converged, 0u);
  ASSERT_LT(serial.cells_converged, cells.size());
  for (const unsigned threads : {2u, 3u, 8u}) {
    SCOPED_TRACE(threads);
    config.threads = threads;
    const auto parallel = dog::runOfflineEm(sequences, sensor, config);
    ASSERT_EQ(parallel.params.size(), serial.params.size());
    ASSERT_EQ(parallel.objective.size(), serial.objective.size());
    std::size_t differences = 0;
    for (std::size_t c = 0; c < cells.size(); ++c) {
      differences +=
          bits(parallel.params[c].p_occ_given_free) != bits(serial.params[c].p_occ_given_free);
      differences +=
          bits(parallel.params[c].p_free_given_occ) != bits(serial.params[c].p_free_given_occ);
      differences += bits(parallel.final_p_occ[c]) != bits(serial.final_p_occ[c]);
      differences += parallel.final_step[c] != serial.final_step[c];
      differences += parallel.iterations[c] != serial.iterations[c];
    }
    for (std::size_t k = 0; k < serial.objective.size(); ++k) {
      differences += bits(parallel.objective[k]) != bits(serial.objective[k]);
    }
    EXPECT_EQ(differences, 0u);
    EXPECT_EQ(parallel.cells_converged, serial.cells_converged);
  }
}

// =====================================================================================
// 6. EM never loses objective.
// =====================================================================================

TEST(OfflineEmRun, ObjectiveNeverDecreases) {
  const dog::ObservationModel sensor(0.8, 0.1);
  std::mt19937_64 rng(1234);
  const std::vector<Sequence> cells = simulatedCells(rng, sensor, 40, 3000);
  for (auto [name, config] : emConfigs()) {
    SCOPED_TRACE(name);
    config.max_iterations = 40;
    // EM gains from any point of the model's parameter set; initial parameters outside it
    // (asymmetric for a symmetric model, outside the bounds) can lose at the first M-step.
    const bool feasible_start = config.initial_params.p_occ_given_free >= config.p_min &&
                                config.initial_params.p_occ_given_free <= config.p_max &&
                                config.initial_params.p_free_given_occ >= config.p_min &&
                                config.initial_params.p_free_given_occ <= config.p_max &&
                                (!config.symmetric || config.initial_params.p_occ_given_free ==
                                                          config.initial_params.p_free_given_occ);
    const std::size_t first_checked = feasible_start ? 1 : 2;
    SweepCheck sweep;
    // Cell by cell (a sum over cells could hide one cell's loss behind another's gain) ...
    for (std::size_t c = 0; c < cells.size(); ++c) {
      const auto result = dog::runOfflineEm(buildSequences({cells[c]}), sensor, config);
      for (std::size_t k = first_checked; k < result.objective.size(); ++k) {
        const double previous = result.objective[k - 1];
        sweep.check(result.objective[k] >= previous - 1e-9 * std::fabs(previous),
                    result.objective[k], previous,
                    "objective[" + std::to_string(k) + "] >= objective[k-1]",
                    "cell " + std::to_string(c) + " (" + name + ")");
      }
    }
    // ... and summed.
    const auto all = dog::runOfflineEm(buildSequences(cells), sensor, config);
    for (std::size_t k = first_checked; k < all.objective.size(); ++k) {
      const double previous = all.objective[k - 1];
      sweep.check(all.objective[k] >= previous - 1e-9 * std::fabs(previous), all.objective[k],
                  previous, "summed objective[" + std::to_string(k) + "]", name);
    }
    sweep.expectNoFailure();
  }
}

// =====================================================================================
// 7. final_p_occ / final_step: the filtered belief at t_n under the learned parameters.
// =====================================================================================

TEST(OfflineEmRun, FinalBeliefIsTheFilterUnderTheLearnedParameters) {
  std::mt19937_64 rng(555);
  const dog::ObservationModel sensor(0.7, 0.2);
  std::vector<Sequence> cells = simulatedCells(rng, sensor, 100, 1000);
  for (int i = 0; i < 100; ++i) cells.push_back(randomSequence(rng, 20, 1e4, 100000, 4));
  dog::OfflineEmConfig config;  // defaults: cells stop by tolerance or after 100 M-steps
  config.initial_p_occ = 0.4;
  const auto result = dog::runOfflineEm(buildSequences(cells), sensor, config);
  ASSERT_EQ(result.final_p_occ.size(), cells.size());
  SweepCheck sweep;
  for (std::size_t c = 0; c < cells.size(); ++c) {
    EXPECT_EQ(result.final_step[c], cells[c].back().step) << "cell " << c;
    const auto expected =
        referenceForwardBackward(cells[c], sensor, result.params[c], config.initial_p_occ);
    sweep.check(near(result.final_p_occ[c], expected.final_p_occ, 1e-9, 1e-300L),
                result.final_p_occ[c], expected.final_p_occ, "final_p_occ",
                describe(cells[c], sensor, result.params[c], config.initial_p_occ));
  }
  sweep.expectNoFailure();
}

// =====================================================================================
// 8. SequenceBuilder.
// =====================================================================================

namespace {

struct CellSequence {
  dog::CellXY cell;
  Sequence observations;
};

std::vector<CellSequence> contents(const dog::ObservationSequences& sequences) {
  std::vector<CellSequence> result;
  for (std::size_t i = 0; i < sequences.cellCount(); ++i) {
    result.push_back(
        CellSequence{sequences.cell(i), Sequence(sequences.begin(i), sequences.end(i))});
  }
  return result;
}

bool sameContents(const std::vector<CellSequence>& a, const std::vector<CellSequence>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (a[i].cell != b[i].cell || a[i].observations.size() != b[i].observations.size()) {
      return false;
    }
    for (std::size_t k = 0; k < a[i].observations.size(); ++k) {
      const auto& x = a[i].observations[k];
      const auto& y = b[i].observations[k];
      if (x.step != y.step || x.hits != y.hits || x.misses != y.misses) return false;
    }
  }
  return true;
}

}  // namespace

TEST(OfflineEmSequenceBuilder, GroupsPerCellInFirstAppearanceOrder) {
  dog::SequenceBuilder builder;
  // Steps interleaved over cells, as a pass over the recording adds them.
  builder.add(3, 4, 10, 1, 0);
  builder.add(-1, 0, 10, 0, 2);
  builder.add(3, 4, 12, 0, 1);
  builder.add(0, -1, 11, 2, 2);
  builder.add(-1, 0, 15, 1, 1);
  builder.add(3, 4, 20, 3, 0);
  EXPECT_EQ(builder.observationCount(), 6u);
  const auto sequences = builder.build();
  const std::vector<CellSequence> expected = {
      {dog::CellXY{3, 4}, {observation(10, 1, 0), observation(12, 0, 1), observation(20, 3, 0)}},
      {dog::CellXY{-1, 0}, {observation(10, 0, 2), observation(15, 1, 1)}},
      {dog::CellXY{0, -1}, {observation(11, 2, 2)}}};
  EXPECT_TRUE(sameContents(contents(sequences), expected));
  EXPECT_EQ(sequences.cellCount(), 3u);
  EXPECT_EQ(sequences.observationCount(), 6u);
}

TEST(OfflineEmSequenceBuilder, DropAfterForgetsTheLaterStepsAndCellsSeenOnlyThen) {
  // A Mapper going back to a checkpoint at step 11: the observations of steps 12 on go, a
  // cell seen only then goes, and the cells' steps go on from what is left.
  dog::SequenceBuilder builder;
  builder.add(3, 4, 10, 1, 0);
  builder.add(-1, 0, 10, 0, 2);
  builder.add(0, -1, 11, 2, 2);
  builder.add(3, 4, 12, 0, 1);
  builder.add(7, 7, 13, 1, 1);
  builder.add(-1, 0, 15, 1, 1);
  builder.dropAfter(11);
  EXPECT_EQ(builder.observationCount(), 3u);
  builder.add(3, 4, 12, 2, 0);  // step 12 again, with other counts: not added to the old ones
  builder.add(5, 5, 12, 0, 1);
  const auto sequences = builder.build();
  const std::vector<CellSequence> expected = {
      {dog::CellXY{3, 4}, {observation(10, 1, 0), observation(12, 2, 0)}},
      {dog::CellXY{-1, 0}, {observation(10, 0, 2)}},
      {dog::CellXY{0, -1}, {observation(11, 2, 2)}},
      {dog::CellXY{5, 5}, {observation(12, 0, 1)}}};
  EXPECT_TRUE(sameContents(contents(sequences), expected));
  EXPECT_EQ(sequences.cellCount(), 4u);
}

TEST(OfflineEmSequenceBuilder, CoordinatesDoNotCollide) {
  // Cells that a key packing with sign extension or a narrow hash key would confuse.
  const std::int32_t kMax = std::numeric_limits<std::int32_t>::max();
  const std::int32_t kMin = std::numeric_limits<std::int32_t>::min();
  const std::vector<dog::CellXY> cells = {{0, -1},      {1, -1},      {-1, 0},      {-1, -1},
                                          {0, 0},       {kMin, kMax}, {kMax, kMin}, {kMin, kMin},
                                          {kMax, kMax}, {-1, kMin},   {1, 0},       {0, 1}};
  dog::SequenceBuilder builder;
  for (std::size_t i = 0; i < cells.size(); ++i) {
    builder.add(cells[i].x, cells[i].y, static_cast<std::int32_t>(i), 1, 0);
  }
  const auto sequences = builder.build();
  ASSERT_EQ(sequences.cellCount(), cells.size());
  for (std::size_t i = 0; i < cells.size(); ++i) {
    EXPECT_EQ(sequences.cell(i), cells[i]) << i;
    EXPECT_EQ(sequences.end(i) - sequences.begin(i), 1) << i;
  }
}

TEST(OfflineEmSequenceBuilder, SameStepMergesAndSaturates) {
  dog::SequenceBuilder builder;
  builder.add(1, 1, 5, 2, 3);
  builder.add(2, 2, 5, 1, 1);
  builder.add(1, 1, 5, 4, 0);          // same cell and step: counts add up
  builder.add(1, 1, 6, 70000, 65535);  // a single add beyond 65535
  builder.add(1, 1, 7, 60000, 1);
  builder.add(1, 1, 7, 60000, 0xFFFFFFFFu);  // sums beyond 65535 (and beyond 32 bits)
  builder.add(1, 1, 7, 5, 5);
  EXPECT_EQ(builder.observationCount(), 4u);
  const std::vector<CellSequence> expected = {
      {dog::CellXY{1, 1},
       {observation(5, 6, 3), observation(6, 65535, 65535), observation(7, 65535, 65535)}},
      {dog::CellXY{2, 2}, {observation(5, 1, 1)}}};
  EXPECT_TRUE(sameContents(contents(builder.build()), expected));
}

TEST(OfflineEmSequenceBuilder, EarlierStepThrowsAndLeavesTheBuilderUnchanged) {
  // The same adds with and without bad calls in between must build the same sequences.
  dog::SequenceBuilder good;
  dog::SequenceBuilder with_bad_calls;
  const auto add_both = [&](std::int32_t x, std::int32_t y, std::int32_t step, int hits,
                            int misses) {
    good.add(x, y, step, hits, misses);
    with_bad_calls.add(x, y, step, hits, misses);
  };
  add_both(0, 0, 10, 1, 0);
  add_both(5, 5, 12, 0, 1);
  // Cell (0, 0) was last seen at step 10, though other cells have gone further.
  EXPECT_THROW(with_bad_calls.add(0, 0, 9, 7, 7), std::invalid_argument);
  EXPECT_THROW(with_bad_calls.add(5, 5, 11, 7, 7), std::invalid_argument);
  EXPECT_EQ(with_bad_calls.observationCount(), good.observationCount());
  add_both(0, 0, 10, 2, 0);  // still merges into step 10
  add_both(0, 0, 11, 0, 1);
  EXPECT_THROW(with_bad_calls.add(0, 0, 10, 7, 7), std::invalid_argument);
  add_both(7, -7, -3, 1, 1);  // a new cell may start at any step
  add_both(5, 5, 13, 1, 0);
  EXPECT_EQ(with_bad_calls.observationCount(), good.observationCount());
  EXPECT_TRUE(sameContents(contents(with_bad_calls.build()), contents(good.build())));
}

TEST(OfflineEmSequenceBuilder, BuildEmptiesTheBuilder) {
  dog::SequenceBuilder builder;
  builder.add(1, 2, 3, 1, 0);
  builder.add(4, 5, 3, 0, 1);
  const auto first = builder.build();
  EXPECT_EQ(first.cellCount(), 2u);
  EXPECT_EQ(builder.observationCount(), 0u);
  const auto empty = builder.build();
  EXPECT_EQ(empty.cellCount(), 0u);
  EXPECT_EQ(empty.observationCount(), 0u);
  // Reusable afterwards, earlier steps of the old cells included.
  builder.add(4, 5, 1, 2, 2);
  builder.add(1, 2, 0, 0, 0);
  const std::vector<CellSequence> expected = {{dog::CellXY{4, 5}, {observation(1, 2, 2)}},
                                              {dog::CellXY{1, 2}, {observation(0, 0, 0)}}};
  EXPECT_TRUE(sameContents(contents(builder.build()), expected));
}

TEST(OfflineEmSequenceBuilder, BytesAreAboutTheDocumentedSize) {
  std::mt19937_64 rng(8);
  dog::SequenceBuilder builder;
  for (std::int32_t step = 0; step < 200; ++step) {
    for (int beam = 0; beam < 50; ++beam) {
      builder.add(std::uniform_int_distribution<std::int32_t>(0, 99)(rng), 0, step, 1, 0);
    }
  }
  const auto sequences = builder.build();
  const std::size_t observations = sequences.observationCount();
  const std::size_t cells = sequences.cellCount();
  ASSERT_EQ(cells, 100u);
  EXPECT_EQ(sizeof(dog::StepObservation), 8u);
  // The header's "8 bytes per observation plus 16 per cell", give or take a constant.
  EXPECT_GE(sequences.bytes(), 8 * observations + 8 * cells);
  EXPECT_LE(sequences.bytes(), 8 * observations + 16 * cells + 64);
}

// =====================================================================================
// 9. Configuration checks and the empty input.
// =====================================================================================

namespace {

using ConfigChange = void (*)(dog::OfflineEmConfig&);

// One bad value per entry, with the name of the field it breaks.
std::vector<std::pair<std::string, ConfigChange>> badConfigs() {
  using C = dog::OfflineEmConfig;
  return {
      {"initial_p_occ", [](C& c) { c.initial_p_occ = 0.0; }},
      {"initial_p_occ", [](C& c) { c.initial_p_occ = 1.0; }},
      {"initial_p_occ", [](C& c) { c.initial_p_occ = -0.1; }},
      {"initial_p_occ", [](C& c) { c.initial_p_occ = 1.5; }},
      {"initial_p_occ", [](C& c) { c.initial_p_occ = kNaN; }},
      {"initial_params", [](C& c) { c.initial_params.p_occ_given_free = -0.01; }},
      {"initial_params", [](C& c) { c.initial_params.p_free_given_occ = 1.01; }},
      {"initial_params", [](C& c) { c.initial_params.p_occ_given_free = kNaN; }},
      {"initial_params", [](C& c) { c.initial_params.p_free_given_occ = kNaN; }},
      {"prior", [](C& c) { c.prior.p_occ_given_free = 1.01; }},
      {"prior", [](C& c) { c.prior.p_free_given_occ = -0.01; }},
      {"prior", [](C& c) { c.prior.p_occ_given_free = kNaN; }},
      {"prior", [](C& c) { c.prior.p_free_given_occ = kNaN; }},
      {"prior_weight", [](C& c) { c.prior_weight = -1e-9; }},
      {"prior_weight", [](C& c) { c.prior_weight = kNaN; }},
      {"prior_weight", [](C& c) { c.prior_weight = std::numeric_limits<double>::infinity(); }},
      {"p_min", [](C& c) { c.p_min = -1e-9; }},
      {"p_min", [](C& c) { c.p_min = kNaN; }},
      {"p_max", [](C& c) { c.p_max = 1.0 + 1e-9; }},
      {"p_max", [](C& c) { c.p_max = kNaN; }},
      {"p_min",
       [](C& c) {
         c.p_min = 0.3;
         c.p_max = 0.2;
       }},
      {"max_iterations", [](C& c) { c.max_iterations = -1; }},
      // iterations are reported as uint16.
      {"max_iterations", [](C& c) { c.max_iterations = 65536; }},
      {"tolerance", [](C& c) { c.tolerance = -1e-12; }},
      {"tolerance", [](C& c) { c.tolerance = kNaN; }},
  };
}

}  // namespace

TEST(OfflineEmConfig, ValidateRejectsBadFields) {
  EXPECT_NO_THROW(dog::OfflineEmConfig{}.validate());
  // Boundary values that are fine.
  dog::OfflineEmConfig edges;
  edges.p_min = 0.0;
  edges.p_max = 1.0;
  edges.max_iterations = 0;
  edges.tolerance = 0.0;
  edges.initial_params = params(0.0, 1.0);
  edges.prior = params(1.0, 0.0);
  EXPECT_NO_THROW(edges.validate());
  edges.p_min = edges.p_max = 0.2;
  edges.max_iterations = 65535;
  EXPECT_NO_THROW(edges.validate());

  const dog::ObservationModel sensor(0.7, 0.2);
  for (const auto& [field, change] : badConfigs()) {
    dog::OfflineEmConfig config;
    change(config);
    EXPECT_THROW(config.validate(), std::invalid_argument) << field;
    dog::SequenceBuilder builder;
    builder.add(0, 0, 0, 1, 0);
    EXPECT_THROW(dog::runOfflineEm(builder.build(), sensor, config), std::invalid_argument)
        << field;
  }
}

TEST(OfflineEmConfig, ValidateMessageNamesTheField) {
  for (const auto& [field, change] : badConfigs()) {
    dog::OfflineEmConfig config;
    change(config);
    try {
      config.validate();
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos)
          << "message does not name " << field << ": " << e.what();
    }
  }
}

TEST(OfflineEmRun, EmptyInputGivesEmptyResult) {
  const dog::ObservationModel sensor(0.7, 0.2);
  const dog::ObservationSequences empty;
  EXPECT_EQ(empty.cellCount(), 0u);
  EXPECT_EQ(empty.observationCount(), 0u);
  const auto result = dog::runOfflineEm(empty, sensor, dog::OfflineEmConfig{});
  EXPECT_TRUE(result.params.empty());
  EXPECT_TRUE(result.final_p_occ.empty());
  EXPECT_TRUE(result.final_step.empty());
  EXPECT_TRUE(result.iterations.empty());
  for (const double value : result.objective) EXPECT_EQ(value, 0.0);
  EXPECT_EQ(result.cells_converged, 0u);
  EXPECT_FALSE(result.cancelled);
}

// =====================================================================================
// 10. Progress and cancellation.
// =====================================================================================

TEST(OfflineEmRun, ProgressReachesTheTotalAndCanCancel) {
  const dog::ObservationModel sensor(0.8, 0.1);
  std::mt19937_64 rng(3);
  std::vector<Sequence> cells;
  for (int i = 0; i < 3000; ++i) cells.push_back(randomSequence(rng, 10, 100, 10000, 3));
  const auto sequences = buildSequences(cells);
  dog::OfflineEmConfig config;
  config.max_iterations = 5;
  config.threads = 4;

  std::vector<std::pair<std::size_t, std::size_t>> calls;
  std::atomic<int> inside{0};
  std::atomic<bool> concurrent{false};
  const auto result =
      dog::runOfflineEm(sequences, sensor, config, [&](std::size_t done, std::size_t total) {
        if (inside.fetch_add(1) != 0) concurrent = true;
        calls.emplace_back(done, total);
        inside.fetch_sub(1);
        return true;
      });
  EXPECT_FALSE(result.cancelled);
  EXPECT_FALSE(concurrent);
  ASSERT_FALSE(calls.empty());
  EXPECT_EQ(calls.back(), std::make_pair(cells.size(), cells.size()));
  for (std::size_t k = 0; k < calls.size(); ++k) {
    EXPECT_EQ(calls[k].second, cells.size());
    if (k > 0) {
      EXPECT_GE(calls[k].first, calls[k - 1].first);
    }
  }

  std::size_t cancel_calls = 0;
  const auto cancelled =
      dog::runOfflineEm(sequences, sensor, config, [&](std::size_t, std::size_t) {
        ++cancel_calls;
        return false;
      });
  EXPECT_TRUE(cancelled.cancelled);
  EXPECT_GE(cancel_calls, 1u);
  // A cancelled run stops taking work, so it reports progress fewer times than a full one.
  EXPECT_LT(cancel_calls, calls.size());
}

// =====================================================================================
// 11. Known-parameter recovery.
// =====================================================================================

TEST(OfflineEmRun, RecoversKnownParameters) {
  const dog::ObservationModel sensor(0.8, 0.1);
  const auto truth = params(0.02, 0.05);
  std::mt19937_64 rng(42);
  std::vector<Sequence> cells;
  for (int i = 0; i < 300; ++i) cells.push_back(simulateCell(rng, truth, sensor, 3000, 0.5, 3));
  const auto result = dog::runOfflineEm(buildSequences(cells), sensor, dog::OfflineEmConfig{});
  double mean_p_of = 0.0;
  double mean_p_fo = 0.0;
  for (const auto& learned : result.params) {
    mean_p_of += learned.p_occ_given_free / cells.size();
    mean_p_fo += learned.p_free_given_occ / cells.size();
  }
  EXPECT_NEAR(mean_p_of, truth.p_occ_given_free, 0.005);
  EXPECT_NEAR(mean_p_fo, truth.p_free_given_occ, 0.005);
}

// =====================================================================================
// The sensor model learned with the transitions (OfflineEmConfig::learn_sensor_model).
// =====================================================================================

TEST(OfflineEmSensorModel, RecoversTheSimulatedSensorFromAWrongStart) {
  std::mt19937_64 rng(4242);
  const dog::ObservationModel truth(0.93, 0.04);
  std::vector<Sequence> cells;
  // Mostly static cells (walls and free space) and some that change, as in a building.
  for (int i = 0; i < 600; ++i) {
    const dog::TransitionParams cell_truth =
        i % 3 == 0 ? params(0.0, 0.0) : (i % 3 == 1 ? params(0.0005, 0.002) : params(0.05, 0.1));
    cells.push_back(simulateCell(rng, cell_truth, truth, 400, 0.5, 3));
  }
  const dog::ObservationSequences sequences = buildSequences(cells);
  dog::OfflineEmConfig config;
  config.threads = 2;
  config.prior_weight = 2.0;
  const dog::ObservationModel start(0.7, 0.2);
  const dog::OfflineEmResult fixed = dog::runOfflineEm(sequences, start, config);
  config.learn_sensor_model = true;
  const dog::OfflineEmResult learned = dog::runOfflineEm(sequences, start, config);
  EXPECT_NEAR(learned.p_hit_given_occ, truth.pHitGivenOcc(), 0.01);
  EXPECT_NEAR(learned.p_hit_given_free, truth.pHitGivenFree(), 0.01);
  EXPECT_GT(learned.sensor_model_rounds, 1);
  EXPECT_EQ(fixed.p_hit_given_occ, start.pHitGivenOcc());
  EXPECT_EQ(fixed.sensor_model_rounds, 1);
  // Coordinate ascent: the likelihood with the learned sensor model is higher.
  EXPECT_GT(learned.objective.back(), fixed.objective.back());
  // The same for any number of threads.
  config.threads = 1;
  const dog::OfflineEmResult one_thread = dog::runOfflineEm(sequences, start, config);
  EXPECT_EQ(bits(one_thread.p_hit_given_occ), bits(learned.p_hit_given_occ));
  EXPECT_EQ(bits(one_thread.p_hit_given_free), bits(learned.p_hit_given_free));
  // Not with the MRF.
  config.mrf_temperature = 50.0;
  EXPECT_THROW(config.validate(), std::invalid_argument);
}

TEST(OfflineEmFixedPointSum, IsExactInAnyOrderAndSurvivesItsHalves) {
  std::mt19937_64 rng(99);
  std::uniform_real_distribution<double> value(0.0, 1e6);
  std::vector<double> values(5000);
  for (double& v : values) v = value(rng) * (rng() % 7 == 0 ? 1e-9 : 1.0);
  dog::FixedPointSum forward;
  for (const double v : values) forward.add(v);
  std::shuffle(values.begin(), values.end(), rng);
  dog::FixedPointSum first_half;
  dog::FixedPointSum second_half;
  for (std::size_t i = 0; i < values.size(); ++i) (i % 3 == 0 ? first_half : second_half).add(values[i]);
  second_half.add(first_half);
  EXPECT_TRUE(second_half == forward);
  const dog::FixedPointSum copy = dog::FixedPointSum::fromHalves(forward.high(), forward.low());
  EXPECT_TRUE(copy == forward);
  EXPECT_EQ(bits(copy.value()), bits(forward.value()));
  LD reference = 0.0L;
  for (const double v : values) reference += static_cast<LD>(v);
  EXPECT_NEAR(forward.value(), static_cast<double>(reference), 1e-9 * static_cast<double>(values.size()));
  dog::FixedPointSum bad;
  EXPECT_THROW(bad.add(-1.0), std::invalid_argument);
  EXPECT_THROW(bad.add(std::numeric_limits<double>::quiet_NaN()), std::invalid_argument);
  EXPECT_THROW(bad.add(std::numeric_limits<double>::infinity()), std::invalid_argument);
}

// Sharded offline EM learns the sensor model in rounds over blocks of cells, adding the
// blocks' exact sums between rounds: it must give runOfflineEm's result bit for bit.
TEST(OfflineEmSensorModel, RoundsOverTwoPartsOfTheCellsGiveTheWholeRunBitForBit) {
  std::mt19937_64 rng(4343);
  const dog::ObservationModel truth(0.9, 0.06);
  std::vector<Sequence> cells;
  for (int i = 0; i < 400; ++i) {
    const dog::TransitionParams cell_truth = i % 2 == 0 ? params(0.0005, 0.002) : params(0.05, 0.1);
    cells.push_back(simulateCell(rng, cell_truth, truth, 300, 0.5, 3));
  }
  std::vector<Sequence> part_cells[2];
  for (std::size_t i = 0; i < cells.size(); ++i) part_cells[i % 5 == 0 ? 0 : 1].push_back(cells[i]);
  const dog::ObservationSequences whole_sequences = buildSequences(cells);
  const dog::ObservationSequences parts[2] = {buildSequences(part_cells[0]), buildSequences(part_cells[1])};
  dog::OfflineEmConfig config;
  config.learn_sensor_model = true;
  config.prior_weight = 2.0;
  const dog::ObservationModel start(0.7, 0.2);
  const dog::OfflineEmResult whole = dog::runOfflineEm(whole_sequences, start, config);
  ASSERT_GT(whole.sensor_model_rounds, 2);

  dog::ObservationModel current = start;
  dog::OfflineEmResult results[2];
  int rounds = 0;
  std::array<dog::FixedPointSum, 2> trials{};
  std::array<dog::FixedPointSum, 2> hits{};
  for (int round = 0; round < config.sensor_model_rounds; ++round) {
    trials = {};
    hits = {};
    for (int p = 0; p < 2; ++p) {
      results[p] = dog::runOfflineEmRound(parts[p], current, config, round == 0 ? std::vector<dog::TransitionParams>{}
                                                                               : results[p].params);
      for (int state = 0; state < 2; ++state) {
        trials[state].add(results[p].sensor_trials_sum[state]);
        hits[state].add(results[p].sensor_hits_sum[state]);
      }
    }
    ++rounds;
    if (round + 1 == config.sensor_model_rounds) break;
    const std::optional<dog::ObservationModel> next = dog::nextSensorModel(trials, hits, current, config);
    if (!next) break;
    current = *next;
  }
  // The last round's sums (the model file keeps them), whichever way the rounds ended.
  for (int state = 0; state < 2; ++state) {
    EXPECT_TRUE(trials[state] == whole.sensor_trials_sum[state]);
    EXPECT_TRUE(hits[state] == whole.sensor_hits_sum[state]);
    EXPECT_EQ(bits(trials[state].value()), bits(whole.sensor_trials[state]));
  }
  EXPECT_EQ(rounds, whole.sensor_model_rounds);
  EXPECT_EQ(bits(current.pHitGivenOcc()), bits(whole.p_hit_given_occ));
  EXPECT_EQ(bits(current.pHitGivenFree()), bits(whole.p_hit_given_free));
  std::size_t next_in_part[2] = {0, 0};
  for (std::size_t i = 0; i < cells.size(); ++i) {
    const int p = i % 5 == 0 ? 0 : 1;
    const std::size_t k = next_in_part[p]++;
    EXPECT_EQ(bits(results[p].params[k].p_occ_given_free), bits(whole.params[i].p_occ_given_free)) << i;
    EXPECT_EQ(bits(results[p].params[k].p_free_given_occ), bits(whole.params[i].p_free_given_occ)) << i;
    EXPECT_EQ(bits(results[p].final_p_occ[k]), bits(whole.final_p_occ[i])) << i;
  }
  EXPECT_THROW(dog::runOfflineEmRound(parts[0], start, config, std::vector<dog::TransitionParams>(3)),
               std::invalid_argument);
  config.learn_sensor_model = false;
  EXPECT_THROW(dog::runOfflineEmRound(parts[0], start, config, {}), std::invalid_argument);
}
