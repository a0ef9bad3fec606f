// Tests of the kinds of cells (core/cell/cell_kinds.h; docs/online_learning.md, "Kinds of cells").
//
// The oracle is a plain reference written here in long double: the model of cell_kinds.h as
// a hidden Markov model on (kind, state), one loop iteration per time step, no closed forms
// (the unobserved steps move each kind's state by its A_k, the kind switch redraws the kind
// from the shares with the state kept, the observed step moves the state, switches it with
// the configured probability for the step's view change, and weighs it by the evidence). No reference calls CellKinds' model. The M-step is checked against its formula
// by hand, and the learning against a simulated population whose kinds are known.

#include "dynamic_occupancy_grid/core/cell/cell_kinds.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <random>
#include <stdexcept>
#include <vector>

namespace dog = dynamic_occupancy_grid::core;

namespace {

using LD = long double;
constexpr int K = dog::kKindCount;
using Joint = std::array<LD, 2 * K>;  // p(k, s) at 2k + s, s: 0 = occ, 1 = free

dog::KindsConfig randomConfig(std::mt19937_64& rng, double switch_probability) {
  std::uniform_real_distribution<double> rate(0.001, 0.45);
  std::uniform_real_distribution<double> share(0.1, 1.0);
  dog::KindsConfig config;
  double total = 0.0;
  for (int k = 0; k < K; ++k) {
    config.initial_transitions[k] = dog::TransitionParams{rate(rng), rate(rng)};
    config.initial_weights[k] = share(rng);
    total += config.initial_weights[k];
  }
  for (double& w : config.initial_weights) w /= total;
  config.switch_probability = switch_probability;
  return config;
}

LD total(const Joint& joint) {
  LD sum = 0.0L;
  for (const LD value : joint) sum += value;
  return sum;
}

// One unobserved step of every kind: x_t = x_{t-1} A_k.
void referenceStep(Joint& joint, const dog::CellKinds& kinds) {
  for (int k = 0; k < K; ++k) {
    const LD of = kinds.transitions(k).p_occ_given_free;
    const LD fo = kinds.transitions(k).p_free_given_occ;
    const LD occ = joint[2 * k] * (1.0L - fo) + joint[2 * k + 1] * of;
    const LD free = joint[2 * k] * fo + joint[2 * k + 1] * (1.0L - of);
    joint[2 * k] = occ;
    joint[2 * k + 1] = free;
  }
}

// The kind switch for `steps` steps: keep (1 - eps)^steps, the rest redrawn from the
// shares with the state kept.
void referenceSwitch(Joint& joint, const dog::CellKinds& kinds, std::int64_t steps) {
  LD keep = 1.0L;
  for (std::int64_t i = 0; i < steps; ++i) keep *= 1.0L - static_cast<LD>(kinds.config().switch_probability);
  const LD all = total(joint);
  LD occ = 0.0L;
  for (int k = 0; k < K; ++k) occ += joint[2 * k];
  const LD state[2] = {occ, all - occ};
  for (int k = 0; k < K; ++k) {
    for (int s = 0; s < 2; ++s) joint[2 * k + s] = keep * joint[2 * k + s] + (1.0L - keep) * kinds.weight(k) * state[s];
  }
}

// The state's switch at an observed step whose view changed by `view_change`, in every kind,
// from occupied and from free: the learned switches (viewSwitch, checked on their own in
// TheViewsSwitchIsLearnedFromTheStableKindsPairs) times the view's change.
std::array<LD, 2> referenceSwitchAtObservation(const dog::CellKinds& kinds, LD view_change) {
  return {static_cast<LD>(kinds.viewSwitch()[0]) * view_change, static_cast<LD>(kinds.viewSwitch()[1]) * view_change};
}

// An observed step after `gap` unobserved ones; fills xi[k][i][j] = p(k, x_{t-1} = i,
// x_t = j | z_1:t). Returns p(occ).
LD referenceObserve(Joint& joint, const dog::CellKinds& kinds, std::int64_t gap, LD ratio, LD xi[K][2][2],
                    LD view_change = 1.0L) {
  for (std::int64_t i = 0; i < gap; ++i) referenceStep(joint, kinds);
  referenceSwitch(joint, kinds, gap + 1);
  const LD b[2] = {std::exp(ratio), 1.0L};  // p(z | occ) / p(z | free), p(z | free) / p(z | free)
  LD c = 0.0L;
  for (int k = 0; k < K; ++k) {
    const LD of = kinds.transitions(k).p_occ_given_free;
    const LD fo = kinds.transitions(k).p_free_given_occ;
    const LD step[2][2] = {{1.0L - fo, fo}, {of, 1.0L - of}};
    const std::array<LD, 2> sigma = referenceSwitchAtObservation(kinds, view_change);
    const LD flip[2][2] = {{1.0L - sigma[0], sigma[0]}, {sigma[1], 1.0L - sigma[1]}};
    LD a[2][2];
    for (int i = 0; i < 2; ++i) {
      for (int j = 0; j < 2; ++j) a[i][j] = step[i][0] * flip[0][j] + step[i][1] * flip[1][j];
    }
    for (int i = 0; i < 2; ++i) {
      for (int j = 0; j < 2; ++j) {
        xi[k][i][j] = joint[2 * k + i] * a[i][j] * b[j];
        c += xi[k][i][j];
      }
    }
  }
  LD occ = 0.0L;
  for (int k = 0; k < K; ++k) {
    for (int i = 0; i < 2; ++i) {
      for (int j = 0; j < 2; ++j) xi[k][i][j] /= c;
    }
    joint[2 * k] = xi[k][0][0] + xi[k][1][0];
    joint[2 * k + 1] = xi[k][0][1] + xi[k][1][1];
    occ += joint[2 * k];
  }
  return occ;
}

Joint toReference(const dog::KindJoint& joint) {
  Joint out;
  for (int i = 0; i < 2 * K; ++i) out[i] = joint.p[i];
  return out;
}

}  // namespace

// One observed step after `gap` unobserved ones, by CellKinds (skip, observe) and by the
// reference: p(occ) and the joint must agree.
void observeBoth(const dog::CellKinds& kinds, std::int64_t gap, double ratio, dog::KindJoint& joint, Joint& reference,
                 double view_change = 1.0) {
  kinds.skip(joint, gap);
  const double p = kinds.observe(joint, gap, ratio, view_change);
  LD xi[K][2][2];
  const LD expected = referenceObserve(reference, kinds, gap, ratio, xi, view_change);
  ASSERT_NEAR(p, static_cast<double>(expected), 1e-12);
  for (int i = 0; i < 2 * K; ++i) ASSERT_NEAR(joint.p[i], static_cast<double>(reference[i]), 1e-12) << i;
}

TEST(CellKinds, ObserveAndSkipEqualTheStepByStepReference) {
  std::mt19937_64 rng(11);
  std::uniform_int_distribution<int> gaps(0, 40);
  std::uniform_real_distribution<double> ratios(-6.0, 6.0);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  for (int trial = 0; trial < 20; ++trial) {
    SCOPED_TRACE(trial);
    dog::KindsConfig config = randomConfig(rng, trial % 2 == 0 ? 1e-3 : 0.0);
    config.view_switch_probability = trial % 5 == 0 ? 0.0 : 0.3 * unit(rng);
    const dog::CellKinds kinds(config, 1e-4, 0.5);
    dog::KindJoint joint = kinds.newCell(0.3);
    Joint reference = toReference(joint);
    for (int step = 0; step < 60; ++step) {
      const std::int64_t gap = step == 0 ? 0 : gaps(rng);
      const double ratio = ratios(rng);
      const double view_change = step % 3 == 0 ? 1.0 : unit(rng);
      ASSERT_NO_FATAL_FAILURE(observeBoth(kinds, gap, ratio, joint, reference, view_change));
    }
  }
}

TEST(CellKinds, GapsAtAndBeyondTheTablesEqualTheStepByStepReference) {
  // lambda_k^n and the switch's keep are tabulated up to 64 steps and computed beyond: the
  // filter must not tell the two apart.
  std::mt19937_64 rng(17);
  std::uniform_real_distribution<double> ratios(-6.0, 6.0);
  const dog::CellKinds kinds(randomConfig(rng, 1e-3), 1e-4, 0.5);
  dog::KindJoint joint = kinds.newCell(0.6);
  Joint reference = toReference(joint);
  for (const std::int64_t gap : {0, 62, 63, 64, 65, 66, 130, 700}) {
    SCOPED_TRACE(gap);
    const double ratio = ratios(rng);
    ASSERT_NO_FATAL_FAILURE(observeBoth(kinds, gap, ratio, joint, reference));
  }
}

TEST(CellKinds, PairPosteriorIsTheChainStepByStepFromEachState) {
  // p(k, x_last = i, x_now = j | z): the joint at the last step, each (kind, state) moved n
  // steps by its A_k one step at a time, switched at the observed step, weighed by this
  // step's evidence.
  std::mt19937_64 rng(13);
  std::uniform_real_distribution<double> ratios(-6.0, 6.0);
  const dog::CellKinds kinds(randomConfig(rng, 1e-3), 1e-4, 0.5);
  dog::KindJoint last = kinds.newCell(0.4);
  kinds.observe(last, 0, 1.5);
  kinds.observe(last, 3, -0.7);
  for (const std::int64_t n : {1, 2, 7, 40, 64, 65, 333}) {
    SCOPED_TRACE(n);
    const double ratio = ratios(rng);
    const double view_change = n % 2 == 0 ? 1.0 : 0.25;
    const dog::CellKinds::PairPosterior pair = kinds.pairPosterior(last, n, ratio, view_change);
    LD expected[K][2][2];
    LD total = 0.0L;
    for (int k = 0; k < K; ++k) {
      const std::array<LD, 2> sigma = referenceSwitchAtObservation(kinds, view_change);
      for (int i = 0; i < 2; ++i) {
        Joint chain{};
        chain[2 * k + i] = 1.0L;
        for (std::int64_t step = 0; step < n; ++step) referenceStep(chain, kinds);
        const LD occ = chain[2 * k] * (1.0L - sigma[0]) + chain[2 * k + 1] * sigma[1];
        const LD now[2] = {occ, chain[2 * k] + chain[2 * k + 1] - occ};
        for (int j = 0; j < 2; ++j) {
          expected[k][i][j] = static_cast<LD>(last.p[2 * k + i]) * now[j] * (j == 0 ? std::exp(static_cast<LD>(ratio)) : 1.0L);
          total += expected[k][i][j];
        }
      }
    }
    for (int k = 0; k < K; ++k) {
      for (int i = 0; i < 2; ++i) {
        for (int j = 0; j < 2; ++j) ASSERT_NEAR(pair[k][i][j], static_cast<double>(expected[k][i][j] / total), 1e-12);
      }
    }
  }
}

TEST(CellKinds, SkippedStepsAreTheMixtureStepByStep) {
  std::mt19937_64 rng(12);
  const dog::CellKinds kinds(randomConfig(rng, 1e-3), 1e-4, 0.5);
  dog::KindJoint joint = kinds.newCell(0.5);
  kinds.observe(joint, 0, 2.5);
  kinds.observe(joint, 3, -1.5);
  Joint reference = toReference(joint);
  for (std::int64_t steps = 0; steps <= 300; ++steps) {
    SCOPED_TRACE(steps);
    LD occ = 0.0L;
    for (int k = 0; k < K; ++k) occ += reference[2 * k];
    dog::KindJoint ahead = joint;
    kinds.skip(ahead, steps);
    double ahead_total = 0.0;
    for (const double value : ahead.p) ahead_total += value;
    ASSERT_NEAR(ahead.occupancy() / ahead_total, static_cast<double>(occ / total(reference)), 1e-12);
    referenceStep(reference, kinds);  // no switch between observations: skipping keeps the kind
  }
}

TEST(CellKinds, ExtremeEvidenceStaysFinite) {
  const dog::CellKinds kinds(dog::KindsConfig{}, 1e-4, 0.5);
  for (const double ratio : {-1e6, -800.0, 800.0, 1e6}) {
    dog::KindJoint joint = kinds.newCell(0.5);
    for (int step = 0; step < 5; ++step) {
      const double p = kinds.observe(joint, step, ratio);
      ASSERT_TRUE(std::isfinite(p));
      EXPECT_NEAR(p, ratio > 0.0 ? 1.0 : 0.0, 1e-12);
      for (const double value : joint.p) ASSERT_TRUE(std::isfinite(value) && value >= 0.0);
    }
  }
}

TEST(CellKinds, NoKindDiesOfEvidence) {
  // A cell seen free ten thousand times keeps every kind alive (the kind switch), so that a
  // place that starts to change is recognised again within a few observations.
  const dog::CellKinds kinds(dog::KindsConfig{}, 1e-4, 0.5);
  dog::KindJoint joint = kinds.newCell(0.5);
  for (int step = 0; step < 10000; ++step) kinds.observe(joint, 0, -8.0);
  for (int k = 0; k < K; ++k) EXPECT_GT(joint.kind(k), 1e-6) << k;
  // Now it flickers: occupied, free, occupied, ... (a laser's hit or miss, log-odds 8). The
  // fastest kind takes over.
  for (int step = 0; step < 12; ++step) kinds.observe(joint, 0, step % 2 == 0 ? 8.0 : -8.0);
  EXPECT_GT(joint.kind(K - 1), 0.5);
}

TEST(CellKinds, OneStepPairsGiveTheCountRatioAndForget) {
  // With pairs one step apart only and no switch at the observed step, the likelihood's
  // maximum is the ratio of the expected transitions with the start's pseudo-transitions;
  // the sums decay first.
  dog::KindsConfig config;
  config.view_switch_probability = 0.0;
  config.transition_prior_weight = 10.0;
  config.weight_prior_cells = 4.0;
  config.forgetting = 0.5;
  dog::CellKinds kinds(config, 1e-4, 0.5);
  dog::CellKinds::Sums sums;
  auto& one_step = sums.pairs[2][dog::gapBin(1)];
  one_step[2 * 1 + 0] = 6.0;   // free -> occ
  one_step[2 * 1 + 1] = 14.0;  // free -> free
  one_step[2 * 0 + 1] = 3.0;   // occ -> free
  one_step[2 * 0 + 0] = 1.0;   // occ -> occ
  sums.membership[2] = 2.0;
  sums.cells = 2.0;
  std::array<dog::TransitionParams, K> start;
  for (int k = 0; k < K; ++k) start[k] = kinds.transitions(k);
  kinds.restore(sums, start);
  kinds.update();  // the sums decay by 1 - forgetting first: 3, 7, 1.5, 0.5
  const dog::TransitionParams prior = config.initial_transitions[2];
  const double of = (3.0 + 10.0 * prior.p_occ_given_free) / (10.0 + 10.0);
  const double fo = (1.5 + 10.0 * prior.p_free_given_occ) / (2.0 + 10.0);
  EXPECT_NEAR(kinds.transitions(2).p_occ_given_free, of, 1e-6 * of);
  EXPECT_NEAR(kinds.transitions(2).p_free_given_occ, fo, 1e-6 * fo);
  // A kind without pairs stays at its start.
  EXPECT_NEAR(kinds.transitions(0).p_occ_given_free, config.initial_transitions[0].p_occ_given_free, 1e-9);
  // Shares: (membership + weight_prior_cells * initial share) / (cells + weight_prior_cells).
  for (int k = 0; k < K; ++k) {
    const double expected = ((k == 2 ? 2.0 : 0.0) + 4.0 * config.initial_weights[k]) / (2.0 + 4.0);
    EXPECT_NEAR(kinds.weight(k), expected, 1e-15) << k;
  }
}

TEST(CellKinds, PairsAtManyDistancesGiveTheChainBack) {
  // The expected pairs of a chain (0.03, 0.07) in its stationary distribution, each pair's
  // state switched at its observed step from a new view (view_switch_probability), a million
  // at each of several distances, some of them longer than the chain's memory: the maximum
  // is that chain (the start's 100 pseudo-pairs move it by less than 0.1 %).
  const double a = 0.03;
  const double b = 0.07;
  const double pi = a / (a + b);
  const double flip = dog::KindsConfig{}.view_switch_probability;  // no pairs of the stable kind: the start
  dog::CellKinds kinds(dog::KindsConfig{}, 1e-4, 0.5);
  dog::CellKinds::Sums sums;
  for (const int bin : {dog::gapBin(1), dog::gapBin(3), dog::gapBin(9), dog::gapBin(40), dog::gapBin(300)}) {
    const double n = dog::gapBinSteps(bin);
    const double decay = std::pow(1.0 - a - b, n);
    const double chain_occ_to_occ = pi + decay * (1.0 - pi);
    const double chain_free_to_occ = pi * (1.0 - decay);
    const double occ_to_occ = chain_occ_to_occ + flip * (1.0 - 2.0 * chain_occ_to_occ);
    const double free_to_occ = chain_free_to_occ + flip * (1.0 - 2.0 * chain_free_to_occ);
    auto& c = sums.pairs[3][bin];
    c[0] = 1e6 * pi * occ_to_occ;
    c[1] = 1e6 * pi * (1.0 - occ_to_occ);
    c[2] = 1e6 * (1.0 - pi) * free_to_occ;
    c[3] = 1e6 * (1.0 - pi) * (1.0 - free_to_occ);
  }
  std::array<dog::TransitionParams, K> start;
  for (int k = 0; k < K; ++k) start[k] = kinds.transitions(k);
  kinds.restore(sums, start);
  kinds.update();
  EXPECT_NEAR(kinds.transitions(3).p_occ_given_free, a, 1e-3 * a);
  EXPECT_NEAR(kinds.transitions(3).p_free_given_occ, b, 1e-3 * b);
  // Only pairs far apart (the chain forgotten between them) still give its long-run
  // occupancy.
  const double seen = pi + flip * (1.0 - 2.0 * pi);  // the long-run state, switched
  dog::CellKinds::Sums far;
  far.pairs[3][dog::gapBin(2000)] = {1e6 * pi * seen, 1e6 * pi * (1.0 - seen), 1e6 * (1.0 - pi) * seen,
                                     1e6 * (1.0 - pi) * (1.0 - seen)};
  dog::CellKinds forgetful(dog::KindsConfig{}, 1e-4, 0.5);
  forgetful.restore(far, start);
  forgetful.update();
  const dog::TransitionParams t = forgetful.transitions(3);
  EXPECT_NEAR(t.p_occ_given_free / (t.p_occ_given_free + t.p_free_given_occ), pi, 1e-3);
}

TEST(CellKinds, MostProbableCountingGivesThePairToTheLikeliestKind) {
  dog::KindsConfig config;
  config.forgetting = 0.0;
  dog::CellKinds kinds(config, 1e-4, 0.5);
  // Kind 3 holds 0.6 of the cell, kind 1 0.4, all of it free; no evidence now.
  dog::KindJoint last;
  last.p[2 * 3 + 1] = 0.6;
  last.p[2 * 1 + 1] = 0.4;
  kinds.addPair(last, 1, 0.0);
  const auto& hard = kinds.sums().pairs;
  const double to_kind_3 = hard[3][0][2] + hard[3][0][3];
  EXPECT_NEAR(to_kind_3, 1.0, 1e-12);  // the whole pair, given kind 3
  // Free to occupied: kind 3's transition, then the observed step's switch.
  const double of = kinds.transitions(3).p_occ_given_free;
  EXPECT_NEAR(hard[3][0][2], of + config.view_switch_probability * (1.0 - 2.0 * of), 1e-12);
  EXPECT_EQ(hard[1][0][2] + hard[1][0][3], 0.0);
  // A pair 50 steps apart goes to its distance's bin.
  kinds.addPair(last, 50, 0.0);
  const auto& bin = kinds.sums().pairs[3][dog::gapBin(50)];
  EXPECT_NEAR(bin[2] + bin[3], 1.0, 1e-12);
}

TEST(CellKinds, DistanceBinsAreExactUpToSixteenThenFourPerOctave) {
  for (int n = 1; n <= 16; ++n) {
    EXPECT_EQ(dog::gapBin(n), n - 1);
    EXPECT_EQ(dog::gapBinSteps(n - 1), n);
  }
  EXPECT_EQ(dog::gapBin(17), 16);
  EXPECT_EQ(dog::gapBin(32), 20);
  EXPECT_EQ(dog::gapBin(std::int64_t{1} << 31), dog::kGapBins - 1);
  EXPECT_EQ(dog::gapBin(std::int64_t{1} << 40), dog::kGapBins - 1);
  for (int bin = 16; bin < dog::kGapBins; ++bin) {
    const double n = dog::gapBinSteps(bin);
    EXPECT_EQ(dog::gapBin(static_cast<std::int64_t>(n)), bin) << bin;
  }
}

TEST(CellKinds, SummaryOfAKnownPosterior) {
  dog::KindsConfig config;
  config.initial_transitions = {{{1e-4, 1e-4}, {1e-3, 2e-3}, {0.01, 0.02}, {0.05, 0.05}, {0.2, 0.4}}};
  dog::KindJoint joint;
  joint.p = {0.45, 0.45, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.02, 0.08};  // 90 % kind 0, 10 % kind 4
  const dog::CellKinds kinds(config, 1e-4, 0.5);
  const dog::TransitionParams t = kinds.summary(joint);
  EXPECT_NEAR(t.p_occ_given_free, std::exp(0.9 * std::log(1e-4) + 0.1 * std::log(0.2)), 1e-15);
  EXPECT_NEAR(t.p_free_given_occ, std::exp(0.9 * std::log(1e-4) + 0.1 * std::log(0.4)), 1e-15);
}

TEST(CellKinds, TheViewsSwitchIsLearnedFromTheStableKindsPairs) {
  // The stable kind's pairs: 30 from occupied of which 3 changed, 1000 from free of which 2
  // changed, one step apart; with transition_prior_weight 100 pseudo-pairs at the start
  // (0.05): (3 + 5) / (30 + 100) from occupied, (2 + 5) / (1000 + 100) from free. Pairs of
  // the other kinds teach it nothing, and it never exceeds the start.
  dog::KindsConfig config;
  config.forgetting = 0.0;
  dog::CellKinds kinds(config, 1e-4, 0.5);
  EXPECT_EQ(kinds.viewSwitch()[0], 0.05);
  EXPECT_EQ(kinds.viewSwitch()[1], 0.05);
  dog::CellKinds::Sums sums;
  sums.pairs[dog::kStableKind][0] = {27.0, 3.0, 2.0, 998.0};
  sums.pairs[3][0] = {0.0, 500.0, 500.0, 0.0};  // another kind's, all changed
  std::array<dog::TransitionParams, K> start;
  for (int k = 0; k < K; ++k) start[k] = kinds.transitions(k);
  kinds.restore(sums, start);
  EXPECT_EQ(kinds.viewSwitch()[0], 0.05);  // (3 + 5) / 130 = 0.062, at most the start
  EXPECT_NEAR(kinds.viewSwitch()[1], 7.0 / 1100.0, 1e-15);
  sums.pairs[dog::kStableKind][0] = {990.0, 10.0, 1.0, 999.0};
  kinds.restore(sums, start);
  EXPECT_NEAR(kinds.viewSwitch()[0], 15.0 / 1100.0, 1e-15);
  // In the filter, per view's change.
  const std::array<double, 2> half = kinds.observedStepSwitch(0.5);
  EXPECT_NEAR(half[0], 0.5 * 15.0 / 1100.0, 1e-15);
  EXPECT_NEAR(half[1], 0.5 * 6.0 / 1100.0, 1e-15);
  EXPECT_EQ(kinds.observedStepSwitch(0.0)[0], 0.0);
  // A new start resets the bound and the prior.
  kinds.setViewSwitchProbability(0.01);
  EXPECT_NEAR(kinds.viewSwitch()[0], std::min(0.01, 11.0 / 1100.0), 1e-15);
  EXPECT_THROW(kinds.setViewSwitchProbability(0.5), std::invalid_argument);
  EXPECT_NEAR(kinds.viewSwitch()[0], std::min(0.01, 11.0 / 1100.0), 1e-15);
}

TEST(CellKinds, TheStableKindIsNeverLearned) {
  // Pairs that would teach any other kind fast rates leave the stable kind where it was
  // configured; a saved model with other transitions for it is read with the configured ones.
  dog::KindsConfig config;
  config.initial_transitions[dog::kStableKind] = {2e-4, 3e-4};
  dog::CellKinds kinds(config, 1e-4, 0.5);
  dog::KindJoint last;
  last.p[2 * dog::kStableKind] = 1.0;  // all of it occupied, on the stable kind
  for (int i = 0; i < 200; ++i) kinds.addPair(last, 1 + i % 5, -5.0);  // and seen free every time
  kinds.update();
  EXPECT_GT(kinds.sums().pairs[dog::kStableKind][0][1], 0.0);  // the pairs were its
  EXPECT_EQ(kinds.transitions(dog::kStableKind).p_occ_given_free, 2e-4);
  EXPECT_EQ(kinds.transitions(dog::kStableKind).p_free_given_occ, 3e-4);
  std::array<dog::TransitionParams, K> saved;
  for (int k = 0; k < K; ++k) saved[k] = kinds.transitions(k);
  saved[dog::kStableKind] = {0.01, 0.2};
  dog::CellKinds restored(config, 1e-4, 0.5);
  restored.restore(kinds.sums(), saved);
  EXPECT_EQ(restored.transitions(dog::kStableKind).p_free_given_occ, 3e-4);
  EXPECT_EQ(restored.transitions(1).p_free_given_occ, kinds.transitions(1).p_free_given_occ);
}

TEST(CellKinds, AStableCellKeepsItsStateInTheSummary) {
  // A cell all on the stable kind: the summary's long-run occupancy is the cell's state, and
  // predicting it any number of steps ahead with the summary keeps it there; its rates stay
  // as small as the stable kind's.
  const dog::CellKinds kinds(dog::KindsConfig{}, 1e-4, 0.5);
  for (const double q : {0.02, 0.3, 0.97}) {
    SCOPED_TRACE(q);
    dog::KindJoint joint;
    joint.p[2 * dog::kStableKind] = q;
    joint.p[2 * dog::kStableKind + 1] = 1.0 - q;
    const dog::TransitionParams t = kinds.summary(joint);
    EXPECT_NEAR(*dog::stationaryOccupancy(t), q, 1e-12);
    EXPECT_NEAR(dog::predictOccupancy(q, t, 100000), q, 1e-12);
    // The smaller rate is the stable kind's own (the learner's lower bound), the other one
    // in the state's ratio.
    EXPECT_NEAR(std::min(t.p_occ_given_free, t.p_free_given_occ), kinds.transitions(dog::kStableKind).p_occ_given_free,
                1e-15);
  }
  // Half on the stable kind (occupied), half on kind 4 (at 0.2 / 0.4 in the defaults' start):
  // the geometric mean of the kinds' rates, the stable kind's in the ratio of its state.
  dog::KindJoint mixed;
  mixed.p[2 * dog::kStableKind] = 0.45;
  mixed.p[2 * dog::kStableKind + 1] = 0.05;
  mixed.p[2 * 4 + 1] = 0.5;
  const dog::TransitionParams stable = kinds.transitions(dog::kStableKind);
  const dog::TransitionParams fast = kinds.transitions(4);
  const dog::TransitionParams t = kinds.summary(mixed);
  EXPECT_NEAR(t.p_occ_given_free, std::sqrt(9.0 * stable.p_occ_given_free * fast.p_occ_given_free), 1e-15);
  EXPECT_NEAR(t.p_free_given_occ, std::sqrt(stable.p_free_given_occ * fast.p_free_given_occ), 1e-15);
}

TEST(CellKinds, SavedSumsRestoreTheKinds) {
  dog::CellKinds kinds(dog::KindsConfig{}, 1e-4, 0.5);
  dog::KindJoint last;
  last.p[2 * 4 + 1] = 1.0;
  for (int i = 0; i < 30; ++i) kinds.addPair(last, 1, 3.0);
  for (int i = 0; i < 70; ++i) kinds.addPair(last, 1, -3.0);
  kinds.addMembership(std::array<double, K>{{0.0, 0.0, 0.0, 0.0, 5.0}}, true);
  kinds.update();
  std::array<dog::TransitionParams, K> learned;
  for (int k = 0; k < K; ++k) learned[k] = kinds.transitions(k);
  dog::CellKinds restored(dog::KindsConfig{}, 1e-4, 0.5);
  restored.restore(kinds.sums(), learned);
  for (int k = 0; k < K; ++k) {
    EXPECT_EQ(restored.transitions(k).p_occ_given_free, kinds.transitions(k).p_occ_given_free);
    EXPECT_EQ(restored.transitions(k).p_free_given_occ, kinds.transitions(k).p_free_given_occ);
    EXPECT_EQ(restored.weight(k), kinds.weight(k));
  }
  // Both go on the same.
  restored.update();
  kinds.update();
  EXPECT_EQ(restored.transitions(4).p_occ_given_free, kinds.transitions(4).p_occ_given_free);
  dog::CellKinds::Sums bad = kinds.sums();
  bad.membership[1] = -1.0;
  EXPECT_THROW(restored.restore(bad, learned), std::invalid_argument);
  bad = kinds.sums();
  bad.pairs[0][0][0] = std::nan("");
  EXPECT_THROW(restored.restore(bad, learned), std::invalid_argument);
  std::array<dog::TransitionParams, K> outside = learned;
  outside[2].p_free_given_occ = 0.7;
  EXPECT_THROW(restored.restore(kinds.sums(), outside), std::invalid_argument);
}

TEST(CellKinds, ConfigurationIsValidated) {
  EXPECT_NO_THROW(dog::KindsConfig{}.validate());
  const auto refuses = [](const std::function<void(dog::KindsConfig&)>& edit) {
    dog::KindsConfig config;
    edit(config);
    EXPECT_THROW(config.validate(), std::invalid_argument);
  };
  refuses([](dog::KindsConfig& c) { c.initial_transitions[1].p_occ_given_free = 0.0; });
  refuses([](dog::KindsConfig& c) { c.initial_transitions[2].p_free_given_occ = 0.6; });
  refuses([](dog::KindsConfig& c) { c.initial_weights[0] = 0.5; });  // no longer sums to 1
  refuses([](dog::KindsConfig& c) { c.transition_prior_weight = 0.0; });
  refuses([](dog::KindsConfig& c) { c.weight_prior_cells = -1.0; });
  refuses([](dog::KindsConfig& c) { c.switch_probability = 1.0; });
  refuses([](dog::KindsConfig& c) { c.forgetting = -0.1; });
  refuses([](dog::KindsConfig& c) { c.view_switch_probability = 0.5; });
  refuses([](dog::KindsConfig& c) { c.view_switch_probability = -0.01; });
  EXPECT_THROW(dog::CellKinds(dog::KindsConfig{}, 0.0, 0.5), std::invalid_argument);
  EXPECT_THROW(dog::CellKinds(dog::KindsConfig{}, 1e-4, 0.75), std::invalid_argument);
}

namespace {

struct PopulationTruth {
  double of, fo;
  int cells;
};

// The population of LearnsTheKinds...: cells of the given truths (a third occupied at the
// start), observed by one beam of a 0.95 / 0.02 sensor in `visit` consecutive steps of every
// `loop` steps (a robot driving past), a new view at each observed step, `steps` steps.
// Returns each truth's mean absolute error of the cells' summaries, and the kinds.
std::array<double, 3> learnPopulation(const dog::KindsConfig& config, const std::array<PopulationTruth, 3>& truths,
                                      int visit, int loop, int steps, dog::CellKinds& kinds,
                                      double* stable_share_of_static = nullptr) {
  const double hit_occ = 0.95;
  const double hit_free = 0.02;
  const double hit_ratio = std::log(hit_occ / hit_free);
  const double miss_ratio = std::log((1.0 - hit_occ) / (1.0 - hit_free));
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<int> truth_of;
  std::vector<bool> occupied;
  for (std::size_t t = 0; t < truths.size(); ++t) {
    for (int c = 0; c < truths[t].cells; ++c) {
      truth_of.push_back(static_cast<int>(t));
      occupied.push_back(u(rng) < 1.0 / 3.0);
    }
  }
  kinds = dog::CellKinds(config, 1e-4, 0.5);
  std::vector<dog::KindJoint> joints(truth_of.size());
  std::vector<int> last_seen(truth_of.size(), -1);
  for (int step = 0; step < steps; ++step) {
    const bool in_view = step % loop < visit;
    for (std::size_t c = 0; c < truth_of.size(); ++c) {
      const PopulationTruth& truth = truths[static_cast<std::size_t>(truth_of[c])];
      if (step > 0 && u(rng) < (occupied[c] ? truth.fo : truth.of)) occupied[c] = !occupied[c];
      if (!in_view) continue;
      const bool hit = u(rng) < (occupied[c] ? hit_occ : hit_free);
      std::array<double, K> before{};
      const double ratio = hit ? hit_ratio : miss_ratio;
      std::int64_t gap = 0;
      if (last_seen[c] < 0) {
        joints[c] = kinds.newCell(0.5);
      } else {
        for (int k = 0; k < K; ++k) before[k] = joints[c].kind(k);
        gap = step - last_seen[c] - 1;
        kinds.addPair(joints[c], gap + 1, ratio);
        kinds.skip(joints[c], gap);
      }
      kinds.observe(joints[c], gap, ratio);
      std::array<double, K> delta{};
      for (int k = 0; k < K; ++k) delta[k] = joints[c].kind(k) - before[k];
      kinds.addMembership(delta, last_seen[c] < 0);
      last_seen[c] = step;
    }
    if (in_view) kinds.update();
  }
  std::array<double, 3> error{};
  double stable = 0.0;
  for (std::size_t c = 0; c < truth_of.size(); ++c) {
    const PopulationTruth& truth = truths[static_cast<std::size_t>(truth_of[c])];
    const dog::TransitionParams summary = kinds.summary(joints[c]);
    error[static_cast<std::size_t>(truth_of[c])] +=
        0.5 * (std::abs(summary.p_occ_given_free - truth.of) + std::abs(summary.p_free_given_occ - truth.fo)) / truth.cells;
    if (truth_of[c] == 0) stable += joints[c].kind(dog::kStableKind) / truth.cells;
  }
  if (stable_share_of_static != nullptr) *stable_share_of_static = stable;
  return error;
}

// A learned kind within 50 % of each changing truth.
void expectAKindAtEachChangingTruth(const dog::CellKinds& kinds, const std::array<PopulationTruth, 3>& truths) {
  for (std::size_t t = 1; t < truths.size(); ++t) {
    bool found = false;
    for (int k = 0; k < K; ++k) {
      const dog::TransitionParams& learned = kinds.transitions(k);
      found = found || (std::abs(learned.p_occ_given_free - truths[t].of) < 0.5 * truths[t].of &&
                        std::abs(learned.p_free_given_occ - truths[t].fo) < 0.5 * truths[t].fo);
    }
    EXPECT_TRUE(found) << "no kind near " << truths[t].of << " / " << truths[t].fo;
  }
}

}  // namespace

TEST(CellKinds, LearnsTheKindsOfASimulatedPopulation) {
  // 2000 cells that never change, 200 slow (0.01 / 0.02 per step) and 100 fast ones (0.15 /
  // 0.3), each observed every step, 1500 steps, by a laser whose readings do not change with
  // the view (view_switch_probability 0): the map learns a kind at each of the three truths,
  // and each cell's summary lands near its own truth.
  const std::array<PopulationTruth, 3> truths{{{0.0, 0.0, 2000}, {0.01, 0.02, 200}, {0.15, 0.3, 100}}};
  dog::KindsConfig config;
  config.view_switch_probability = 0.0;
  dog::CellKinds kinds(config, 1e-4, 0.5);
  const std::array<double, 3> error = learnPopulation(config, truths, 1, 1, 1500, kinds);
  expectAKindAtEachChangingTruth(kinds, truths);
  // Measured: 0.0050, 0.0051, 0.0079. A static cell's summary holds its state with rates in
  // its state's ratio, the larger at most 99 times the learner's lower bound (about 0.01):
  // its error against 0 / 0 is about 0.005.
  EXPECT_LT(error[0], 0.006);
  EXPECT_LT(error[1], 0.008);
  EXPECT_LT(error[2], 0.02);
}

TEST(CellKinds, LearnsWhatChangesBetweenVisitsWhileViewsSwitch) {
  // The same population seen as a patrolling robot sees it, six steps every hundred, every
  // observed step a new view (view_switch_probability 0.05, the default): what changes
  // between visits is learned as changing, and the cells that never change stay in the
  // stable kind, whose summary keeps them still.
  const std::array<PopulationTruth, 3> truths{{{0.0, 0.0, 2000}, {0.01, 0.02, 200}, {0.15, 0.3, 100}}};
  const dog::KindsConfig config;
  dog::CellKinds kinds(config, 1e-4, 0.5);
  double stable_share = 0.0;
  const std::array<double, 3> error = learnPopulation(config, truths, 6, 100, 6000, kinds, &stable_share);
  expectAKindAtEachChangingTruth(kinds, truths);
  // Measured: 99.6 % of the static cells' posterior on the stable kind; errors 0.0048 (the
  // stable kind's summary, see above), 0.0067, 0.077 (the fast cells' summaries are pulled
  // down by what stays on the stable kind: a geometric mean).
  EXPECT_GT(stable_share, 0.95);
  EXPECT_LT(error[0], 0.006);
  EXPECT_LT(error[1], 0.01);
  EXPECT_LT(error[2], 0.1);
}
