#include "dynamic_occupancy_grid/core/cell/cell_kinds.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace dynamic_occupancy_grid {
namespace core {
namespace {

void require(bool ok, const std::string& message) {
  if (!ok) throw std::invalid_argument(message);
}

// As in online_em.cpp: beyond this the other state's likelihood underflows; clamping keeps
// the normaliser positive and changes nothing else.
constexpr double kMaxLogLikelihoodRatio = 700.0;

// summary(): the stable kind's state q enters its rates as q / min(q, 1 - q) and
// (1 - q) / min(q, 1 - q) times its own, q kept within [0.01, 0.99]: the larger rate at most
// 99 times the stable kind's own (about 0.01 per step), the long-run state q. With q within
// [1/11, 10/11] (rates at most ten times; walls and floor darker in the transition layers)
// the stationary layer kept fewer walls (measured at commit 4a0b4d6: 91.4-96.8 % instead of
// 92.5-97.0 % on the office recordings).
constexpr double kStableStateFloor = 0.01;

// The distance bins: 1..16 steps one each, then four per octave.
constexpr int kExactBins = 16;
constexpr double kBinsPerOctave = 4.0;

// P(x_n = j | x_0 = i), [i][j], of a chain with stationary occupancy pi and lambda^n =
// decay: pi_j + lambda^n (delta_ij - pi_j) (THEORY.md §3).
void nStep(double pi, double decay, double p[2][2]) {
  p[0][0] = pi + decay * (1.0 - pi);
  p[0][1] = 1.0 - p[0][0];
  p[1][0] = pi * (1.0 - decay);
  p[1][1] = 1.0 - p[1][0];
}

// The same for the chain with transitions t, `steps` (not necessarily whole) apart; lambda >= 0
// here (both rates at most 0.5).
void nStep(const TransitionParams& t, double steps, double p[2][2]) {
  nStep(t.p_occ_given_free / (t.p_occ_given_free + t.p_free_given_occ), std::pow(std::max(t.lambda(), 0.0), steps), p);
}

}  // namespace

KindEvidence::KindEvidence(double log_likelihood_ratio) {
  const double ratio = std::clamp(log_likelihood_ratio, -kMaxLogLikelihoodRatio, kMaxLogLikelihoodRatio);
  occ = ratio >= 0.0 ? 1.0 : std::exp(ratio);
  free = ratio >= 0.0 ? std::exp(-ratio) : 1.0;
}

int gapBin(std::int64_t steps) {
  if (steps <= kExactBins) return static_cast<int>(std::max<std::int64_t>(steps, 1)) - 1;
  const double octaves = std::log2(static_cast<double>(steps) / kExactBins);
  return std::min(kExactBins + static_cast<int>(std::floor(kBinsPerOctave * octaves)), kGapBins - 1);
}

double gapBinSteps(int bin) {
  if (bin < kExactBins) return bin + 1.0;
  // The geometric middle of the bin's distances.
  return kExactBins * std::exp2((bin - kExactBins + 0.5) / kBinsPerOctave);
}

void KindsConfig::validate() const {
  double sum = 0.0;
  for (int k = 0; k < kKindCount; ++k) {
    const TransitionParams& t = initial_transitions[k];
    require(t.isValid() && t.p_occ_given_free > 0.0 && t.p_free_given_occ > 0.0 && t.p_occ_given_free <= 0.5 &&
                t.p_free_given_occ <= 0.5,
            "kinds initial_transitions must be in (0, 0.5], kind " + std::to_string(k));
    require(std::isfinite(initial_weights[k]) && initial_weights[k] > 0.0,
            "kinds initial_weights must be > 0, kind " + std::to_string(k));
    sum += initial_weights[k];
  }
  require(std::abs(sum - 1.0) < 1e-6, "kinds initial_weights must sum to 1, got " + std::to_string(sum));
  require(std::isfinite(transition_prior_weight) && transition_prior_weight > 0.0,
          "kinds transition_prior_weight must be > 0, got " + std::to_string(transition_prior_weight));
  require(std::isfinite(weight_prior_cells) && weight_prior_cells > 0.0,
          "kinds weight_prior_cells must be > 0, got " + std::to_string(weight_prior_cells));
  require(switch_probability >= 0.0 && switch_probability < 1.0,
          "kinds switch_probability must be in [0, 1), got " + std::to_string(switch_probability));
  require(view_switch_probability >= 0.0 && view_switch_probability < 0.5,
          "kinds view_switch_probability must be in [0, 0.5), got " + std::to_string(view_switch_probability));
  require(forgetting >= 0.0 && forgetting < 1.0, "kinds forgetting must be in [0, 1), got " + std::to_string(forgetting));
}

CellKinds::CellKinds(const KindsConfig& config, double p_min, double p_max) : config_(config), p_min_(p_min), p_max_(p_max) {
  config_.validate();
  require(p_min > 0.0 && p_min <= p_max && p_max <= 0.5, "kinds need 0 < p_min <= p_max <= 0.5");
  log_keep_ = std::log1p(-config_.switch_probability);
  for (int k = 0; k < kKindCount; ++k) {
    const TransitionParams& start = config_.initial_transitions[k];
    transitions_[k] = TransitionParams{std::clamp(start.p_occ_given_free, p_min_, p_max_),
                                       std::clamp(start.p_free_given_occ, p_min_, p_max_)};
  }
  recompute();
}

double CellKinds::lambdaPower(int k, std::int64_t steps) const {
  if (steps <= 0) return 1.0;
  if (steps <= kTabulatedSteps) return lambda_powers_[steps][k];
  return std::exp(static_cast<double>(steps) * log_lambda_[k]);
}

KindJoint CellKinds::newCell(double initial_p_occ) const {
  KindJoint joint;
  for (int k = 0; k < kKindCount; ++k) {
    joint.p[2 * k] = weights_[k] * initial_p_occ;
    joint.p[2 * k + 1] = weights_[k] * (1.0 - initial_p_occ);
  }
  return joint;
}

void CellKinds::skip(KindJoint& joint, std::int64_t steps) const {
  if (steps <= 0) return;
  for (int k = 0; k < kKindCount; ++k) {
    // p(k, occ) after n steps = p(k) pi_k + lambda_k^n (p(k, occ) - p(k) pi_k).
    const double mass = joint.kind(k);
    const double stationary = mass * pi_[k];
    const double occ = stationary + lambdaPower(k, steps) * (joint.p[2 * k] - stationary);
    joint.p[2 * k] = occ;
    joint.p[2 * k + 1] = mass - occ;
  }
}

double CellKinds::observe(KindJoint& joint, std::int64_t gap, double log_likelihood_ratio, double view_change) const {
  return observe(joint, gap, KindEvidence(log_likelihood_ratio), view_change);
}

double CellKinds::observe(KindJoint& joint, std::int64_t gap, const KindEvidence& evidence, double view_change) const {
  // The kind switch over the gap and this step: mass (1 - keep) redrawn from w, state kept.
  const double keep =
      gap + 1 <= kTabulatedSteps ? keep_powers_[gap + 1] : std::exp(log_keep_ * static_cast<double>(gap + 1));
  const double occ = joint.occupancy();
  double total = 0.0;
  for (const double value : joint.p) total += value;
  const double state[2] = {occ, total - occ};
  for (int k = 0; k < kKindCount; ++k) {
    for (int s = 0; s < 2; ++s) {
      joint.p[2 * k + s] = keep * joint.p[2 * k + s] + (1.0 - keep) * weights_[k] * state[s];
    }
  }
  const double b[2] = {evidence.occ, evidence.free};
  const std::array<double, 2> flip = observedStepSwitch(view_change);
  double next[2 * kKindCount];
  double c = 0.0;
  for (int k = 0; k < kKindCount; ++k) {
    const TransitionParams& t = transitions_[k];
    const double to_occ = joint.p[2 * k] * (1.0 - t.p_free_given_occ) + joint.p[2 * k + 1] * t.p_occ_given_free;
    const double to_free = joint.p[2 * k] * t.p_free_given_occ + joint.p[2 * k + 1] * (1.0 - t.p_occ_given_free);
    // The observed step's switch (the stable kind's only way to change).
    const double occ_now = to_occ * (1.0 - flip[0]) + to_free * flip[1];
    next[2 * k] = occ_now * b[0];
    next[2 * k + 1] = (to_occ + to_free - occ_now) * b[1];
    c += next[2 * k] + next[2 * k + 1];
  }
  const double scale = 1.0 / c;
  for (int i = 0; i < 2 * kKindCount; ++i) joint.p[i] = next[i] * scale;
  return joint.occupancy();
}

TransitionParams CellKinds::summary(const KindJoint& joint) const {
  // One pass, no array of the masses: this runs for every observed cell-step.
  double total = 0.0;
  double log_of = 0.0;
  double log_fo = 0.0;
  for (int k = 0; k < kKindCount; ++k) {
    const double mass = joint.kind(k);
    total += mass;
    log_of += mass * log_p_of_[k];
    log_fo += mass * log_p_fo_[k];
  }
  // The stable kind keeps its state: its two rates in the ratio of its state q to 1 - q,
  // the smaller of them its own, so that the summary's long-run state (the stationary
  // layer) and prediction hold a stable cell where it is, not at its transitions' 1/2, and
  // no rate falls below the learner's bounds.
  const double stable = joint.kind(kStableKind);
  if (stable > 0.0) {
    const double q = std::clamp(joint.p[2 * kStableKind] / stable, kStableStateFloor, 1.0 - kStableStateFloor);
    const double smaller = std::min(q, 1.0 - q);
    log_of += stable * std::log(q / smaller);
    log_fo += stable * std::log((1.0 - q) / smaller);
  }
  return TransitionParams{std::exp(log_of / total), std::exp(log_fo / total)};
}

CellKinds::PairPosterior CellKinds::pairPosterior(const KindJoint& last, std::int64_t steps,
                                                  double log_likelihood_ratio, double view_change) const {
  return pairPosterior(last, steps, KindEvidence(log_likelihood_ratio), view_change);
}

CellKinds::PairPosterior CellKinds::pairPosterior(const KindJoint& last, std::int64_t steps,
                                                  const KindEvidence& evidence, double view_change) const {
  PairPosterior pair = pairWeights(last, steps, evidence, view_change);
  double total = 0.0;
  for (const auto& kind : pair) total += kind[0][0] + kind[0][1] + kind[1][0] + kind[1][1];
  if (!(total > 0.0)) return PairPosterior{};
  const double scale = 1.0 / total;
  for (auto& kind : pair) {
    for (auto& row : kind) {
      for (double& value : row) value *= scale;
    }
  }
  return pair;
}

CellKinds::PairPosterior CellKinds::pairWeights(const KindJoint& last, std::int64_t steps,
                                                const KindEvidence& evidence, double view_change) const {
  const double b[2] = {evidence.occ, evidence.free};
  PairPosterior pair;
  for (int k = 0; k < kKindCount; ++k) {
    for (int i = 0; i < 2; ++i) {
      const double to_occ = occupiedAfter(k, i, steps, view_change);
      pair[k][i][0] = last.p[2 * k + i] * to_occ * b[0];
      pair[k][i][1] = last.p[2 * k + i] * (1.0 - to_occ) * b[1];
    }
  }
  return pair;
}

double CellKinds::occupiedAfter(int k, int s, std::int64_t steps, double view_change) const {
  double p[2][2];
  nStep(pi_[k], lambdaPower(k, steps), p);  // lambda_k^n from the table
  const std::array<double, 2> flip = observedStepSwitch(view_change);
  return p[s][0] * (1.0 - flip[0]) + p[s][1] * flip[1];
}

void CellKinds::addPair(const KindJoint& last, std::int64_t steps, double log_likelihood_ratio, double view_change) {
  addPair(last, steps, KindEvidence(log_likelihood_ratio), view_change);
}

void CellKinds::addPair(const KindJoint& last, std::int64_t steps, const KindEvidence& evidence, double view_change) {
  if (steps < 1) return;
  // The posterior up to its normaliser, which the likeliest kind's share divides out.
  const PairPosterior pair = pairWeights(last, steps, evidence, view_change);
  double mass[kKindCount];
  int best = 0;
  for (int k = 0; k < kKindCount; ++k) {
    mass[k] = pair[k][0][0] + pair[k][0][1] + pair[k][1][0] + pair[k][1][1];
    if (mass[k] > mass[best]) best = k;
  }
  if (!(mass[best] > 0.0)) return;
  // The whole pair to the likeliest kind, given that kind (classification EM).
  const int bin = gapBin(steps);
  const double scale = 1.0 / mass[best];
  for (int c = 0; c < 4; ++c) sums_.pairs[best][bin][c] += scale * pair[best][c / 2][c % 2];
}

void CellKinds::setViewSwitchProbability(double view_switch_probability) {
  KindsConfig changed = config_;
  changed.view_switch_probability = view_switch_probability;
  changed.validate();
  config_ = changed;
  recompute();
}

void CellKinds::addMembership(const std::array<double, kKindCount>& delta, bool new_cell) {
  for (int k = 0; k < kKindCount; ++k) sums_.membership[k] += delta[k];
  if (new_cell) sums_.cells += 1.0;
}

void CellKinds::update() {
  const double decay = 1.0 - config_.forgetting;
  for (auto& kind : sums_.pairs) {
    for (auto& bin : kind) {
      for (double& value : bin) value *= decay;
    }
  }
  for (int k = 0; k < kKindCount; ++k) {
    if (k != kStableKind) transitions_[k] = fitPairs(k, transitions_[k]);
  }
  recompute();
}

void CellKinds::restore(const Sums& sums, const std::array<TransitionParams, kKindCount>& transitions) {
  bool ok = std::isfinite(sums.cells) && sums.cells >= 0.0;
  for (int k = 0; k < kKindCount; ++k) {
    ok = ok && std::isfinite(sums.membership[k]) && sums.membership[k] >= 0.0;
    for (const auto& bin : sums.pairs[k]) {
      for (const double value : bin) ok = ok && std::isfinite(value) && value >= 0.0;
    }
    const TransitionParams& t = transitions[k];
    ok = ok && t.p_occ_given_free >= p_min_ && t.p_occ_given_free <= p_max_ && t.p_free_given_occ >= p_min_ &&
         t.p_free_given_occ <= p_max_;
  }
  require(ok, "kinds: saved sums must be finite and >= 0, transitions within the bounds");
  sums_ = sums;
  // The stable kind is never learned: it keeps the configured transitions, whatever a file
  // written before it existed says.
  const TransitionParams stable = transitions_[kStableKind];
  transitions_ = transitions;
  transitions_[kStableKind] = stable;
  recompute();
}

TransitionParams CellKinds::fitPairs(int k, TransitionParams start) const {
  // Maximise, over (u, v) = (log a, log b) within the bounds, the pairs' log-likelihood plus
  // the start's pseudo-pairs, by Newton steps (finite differences, at most a unit step in
  // log space) with backtracking: a smooth function of two variables, and the maximum of
  // the step before is where this one starts.
  const TransitionParams& prior = config_.initial_transitions[k];
  const double w = config_.transition_prior_weight;
  const auto& bins = sums_.pairs[k];
  const std::array<double, 2> flip = observedStepSwitch(1.0);
  const auto objective = [&](double u, double v) {
    const double a = std::exp(u);
    const double b = std::exp(v);
    double value = w * (prior.p_occ_given_free * u + (1.0 - prior.p_occ_given_free) * std::log1p(-a)) +
                   w * (prior.p_free_given_occ * v + (1.0 - prior.p_free_given_occ) * std::log1p(-b));
    for (int bin = 0; bin < kGapBins; ++bin) {
      const auto& c = bins[bin];
      if (c[0] + c[1] + c[2] + c[3] <= 0.0) continue;
      double p[2][2];
      nStep(TransitionParams{a, b}, gapBinSteps(bin), p);
      for (int i = 0; i < 2; ++i) {
        // Then the observed step's switch, from a new view: a pair's change that the view
        // explains is not the kind's (pairs do not keep their view; most are new ones).
        const double to_occ = p[i][0] * (1.0 - flip[0]) + p[i][1] * flip[1];
        const double now[2] = {to_occ, 1.0 - to_occ};
        for (int j = 0; j < 2; ++j) {
          if (c[2 * i + j] > 0.0) value += c[2 * i + j] * std::log(std::max(now[j], 1e-300));
        }
      }
    }
    return value;
  };
  const double lo = std::log(p_min_);
  const double hi = std::log(p_max_);
  double u = std::clamp(std::log(start.p_occ_given_free), lo, hi);
  double v = std::clamp(std::log(start.p_free_given_occ), lo, hi);
  constexpr double h = 1e-4;
  constexpr int kMaxIterations = 30;
  for (int iteration = 0; iteration < kMaxIterations; ++iteration) {
    const double f0 = objective(u, v);
    const double fu1 = objective(u + h, v);
    const double fu0 = objective(u - h, v);
    const double fv1 = objective(u, v + h);
    const double fv0 = objective(u, v - h);
    const double gu = (fu1 - fu0) / (2.0 * h);
    const double gv = (fv1 - fv0) / (2.0 * h);
    const double huu = (fu1 - 2.0 * f0 + fu0) / (h * h);
    const double hvv = (fv1 - 2.0 * f0 + fv0) / (h * h);
    const double huv = (objective(u + h, v + h) - fu1 - fv1 + f0) / (h * h);
    double du = gu;
    double dv = gv;
    const double det = huu * hvv - huv * huv;
    if (huu < 0.0 && det > 0.0) {  // concave here: the Newton step
      du = -(hvv * gu - huv * gv) / det;
      dv = -(huu * gv - huv * gu) / det;
    }
    // A step that leaves the box along a bound the gradient pushes against is cut there.
    if ((u <= lo && du < 0.0) || (u >= hi && du > 0.0)) du = 0.0;
    if ((v <= lo && dv < 0.0) || (v >= hi && dv > 0.0)) dv = 0.0;
    const double length = std::hypot(du, dv);
    if (length < 1e-10) break;
    if (length > 1.0) {
      du /= length;
      dv /= length;
    }
    bool moved = false;
    for (double step = 1.0; step > 1e-6; step *= 0.5) {
      const double nu = std::clamp(u + step * du, lo, hi);
      const double nv = std::clamp(v + step * dv, lo, hi);
      if (objective(nu, nv) > f0) {
        moved = std::abs(nu - u) + std::abs(nv - v) > 1e-10;
        u = nu;
        v = nv;
        break;
      }
    }
    if (!moved) break;
  }
  return TransitionParams{std::clamp(std::exp(u), p_min_, p_max_), std::clamp(std::exp(v), p_min_, p_max_)};
}

void CellKinds::recompute() {
  {  // viewSwitch()
    double pairs[4] = {0.0, 0.0, 0.0, 0.0};
    for (const auto& bin : sums_.pairs[kStableKind]) {
      for (int c = 0; c < 4; ++c) pairs[c] += bin[c];
    }
    const double start = config_.view_switch_probability;
    const double w = config_.transition_prior_weight;
    switch_[0] = std::min(start, (pairs[1] + w * start) / (pairs[0] + pairs[1] + w));
    switch_[1] = std::min(start, (pairs[2] + w * start) / (pairs[2] + pairs[3] + w));
  }
  double share_total = 0.0;
  for (int k = 0; k < kKindCount; ++k) {
    const double lambda = transitions_[k].lambda();
    log_lambda_[k] = lambda > 0.0 ? std::log(lambda) : -std::numeric_limits<double>::infinity();
    log_p_of_[k] = std::log(transitions_[k].p_occ_given_free);
    log_p_fo_[k] = std::log(transitions_[k].p_free_given_occ);
    pi_[k] = transitions_[k].p_occ_given_free / (transitions_[k].p_occ_given_free + transitions_[k].p_free_given_occ);
    lambda_powers_[0][k] = 1.0;
    for (int n = 1; n <= kTabulatedSteps; ++n) {
      lambda_powers_[n][k] = std::exp(static_cast<double>(n) * log_lambda_[k]);
    }
    weights_[k] = std::max(sums_.membership[k], 0.0) + config_.weight_prior_cells * config_.initial_weights[k];
    share_total += weights_[k];
  }
  for (double& weight : weights_) weight /= share_total;
  for (int n = 0; n <= kTabulatedSteps; ++n) keep_powers_[n] = std::exp(log_keep_ * static_cast<double>(n));
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
