#include "dynamic_occupancy_grid/core/cell_kinds.h"

#include <algorithm>
#include <cmath>
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

}  // namespace

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
  require(forgetting >= 0.0 && forgetting < 1.0, "kinds forgetting must be in [0, 1), got " + std::to_string(forgetting));
}

double KindJoint::occupancy() const {
  double occ = 0.0;
  for (int k = 0; k < kKindCount; ++k) occ += p[2 * k];
  return occ;
}

CellKinds::CellKinds(const KindsConfig& config, double p_min, double p_max) : config_(config), p_min_(p_min), p_max_(p_max) {
  config_.validate();
  require(p_min > 0.0 && p_min <= p_max && p_max <= 0.5, "kinds need 0 < p_min <= p_max <= 0.5");
  log_keep_ = std::log1p(-config_.switch_probability);
  recompute();
}

double CellKinds::lambdaPower(int k, std::int64_t steps) const {
  if (steps <= 0) return 1.0;
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
    const TransitionParams& t = transitions_[k];
    const double mass = joint.kind(k);
    const double stationary = mass * t.p_occ_given_free / (t.p_occ_given_free + t.p_free_given_occ);
    const double occ = stationary + lambdaPower(k, steps) * (joint.p[2 * k] - stationary);
    joint.p[2 * k] = occ;
    joint.p[2 * k + 1] = mass - occ;
  }
}

double CellKinds::observe(KindJoint& joint, std::int64_t gap, double log_likelihood_ratio,
                          KindTransitions* transitions) const {
  // The kind switch over the gap and this step: mass (1 - keep) redrawn from w, state kept.
  const double keep = std::exp(log_keep_ * static_cast<double>(gap + 1));
  const double occ = joint.occupancy();
  double total = 0.0;
  for (const double value : joint.p) total += value;
  const double state[2] = {occ, total - occ};
  for (int k = 0; k < kKindCount; ++k) {
    for (int s = 0; s < 2; ++s) {
      joint.p[2 * k + s] = keep * joint.p[2 * k + s] + (1.0 - keep) * weights_[k] * state[s];
    }
  }
  // b(z) up to a common factor, the larger 1.
  const double ratio = std::clamp(log_likelihood_ratio, -kMaxLogLikelihoodRatio, kMaxLogLikelihoodRatio);
  const double b[2] = {ratio >= 0.0 ? 1.0 : std::exp(ratio), ratio >= 0.0 ? std::exp(-ratio) : 1.0};
  double xi[kKindCount][2][2];
  double c = 0.0;
  for (int k = 0; k < kKindCount; ++k) {
    const TransitionParams& t = transitions_[k];
    const double a[2][2] = {{1.0 - t.p_free_given_occ, t.p_free_given_occ}, {t.p_occ_given_free, 1.0 - t.p_occ_given_free}};
    for (int i = 0; i < 2; ++i) {
      for (int j = 0; j < 2; ++j) {
        xi[k][i][j] = joint.p[2 * k + i] * a[i][j] * b[j];
        c += xi[k][i][j];
      }
    }
  }
  for (int k = 0; k < kKindCount; ++k) {
    for (int j = 0; j < 2; ++j) joint.p[2 * k + j] = (xi[k][0][j] + xi[k][1][j]) / c;
  }
  if (transitions != nullptr) {
    for (int k = 0; k < kKindCount; ++k) {
      for (int i = 0; i < 2; ++i) {
        for (int j = 0; j < 2; ++j) transitions->n[k][i][j] += xi[k][i][j] / c;
      }
    }
  }
  return joint.occupancy();
}

double CellKinds::predict(const KindJoint& joint, std::int64_t steps) const {
  KindJoint ahead = joint;
  skip(ahead, steps);
  double total = 0.0;
  for (const double value : ahead.p) total += value;
  return ahead.occupancy() / total;
}

TransitionParams CellKinds::summary(const KindJoint& joint) const {
  double mass[kKindCount];
  double total = 0.0;
  int best = 0;
  for (int k = 0; k < kKindCount; ++k) {
    mass[k] = joint.kind(k);
    total += mass[k];
    if (mass[k] > mass[best]) best = k;
  }
  switch (config_.summary) {
    case KindSummary::kMostProbable:
      return transitions_[best];
    case KindSummary::kMean: {
      TransitionParams mean;
      for (int k = 0; k < kKindCount; ++k) {
        mean.p_occ_given_free += mass[k] / total * transitions_[k].p_occ_given_free;
        mean.p_free_given_occ += mass[k] / total * transitions_[k].p_free_given_occ;
      }
      return mean;
    }
    case KindSummary::kGeometricMean:
      break;
  }
  double log_of = 0.0;
  double log_fo = 0.0;
  for (int k = 0; k < kKindCount; ++k) {
    log_of += mass[k] / total * log_p_of_[k];
    log_fo += mass[k] / total * log_p_fo_[k];
  }
  return TransitionParams{std::exp(log_of), std::exp(log_fo)};
}

void CellKinds::addTransitions(const KindTransitions& transitions) {
  if (config_.counting == KindCounting::kPosterior) {
    for (int k = 0; k < kKindCount; ++k) {
      for (int i = 0; i < 2; ++i) {
        for (int j = 0; j < 2; ++j) sums_.transitions.n[k][i][j] += transitions.n[k][i][j];
      }
    }
    return;
  }
  // The kind that holds most of the step's mass, and the transitions given that kind.
  int best = 0;
  double best_mass = -1.0;
  for (int k = 0; k < kKindCount; ++k) {
    const auto& n = transitions.n[k];
    const double mass = n[0][0] + n[0][1] + n[1][0] + n[1][1];
    if (mass > best_mass) {
      best = k;
      best_mass = mass;
    }
  }
  if (!(best_mass > 0.0)) return;
  for (int i = 0; i < 2; ++i) {
    for (int j = 0; j < 2; ++j) sums_.transitions.n[best][i][j] += transitions.n[best][i][j] / best_mass;
  }
}

void CellKinds::addMembership(const std::array<double, kKindCount>& delta, bool new_cell) {
  for (int k = 0; k < kKindCount; ++k) sums_.membership[k] += delta[k];
  if (new_cell) sums_.cells += 1.0;
}

void CellKinds::update() {
  const double decay = 1.0 - config_.forgetting;
  for (auto& kind : sums_.transitions.n) {
    for (auto& row : kind) {
      for (double& value : row) value *= decay;
    }
  }
  recompute();
}

void CellKinds::restore(const Sums& sums) {
  bool ok = std::isfinite(sums.cells) && sums.cells >= 0.0;
  for (int k = 0; k < kKindCount; ++k) {
    ok = ok && std::isfinite(sums.membership[k]) && sums.membership[k] >= 0.0;
    for (const auto& row : sums.transitions.n[k]) {
      for (const double value : row) ok = ok && std::isfinite(value) && value >= 0.0;
    }
  }
  require(ok, "kinds: saved sums must be finite and >= 0");
  sums_ = sums;
  recompute();
}

void CellKinds::recompute() {
  const double w = config_.transition_prior_weight;
  double share_total = 0.0;
  for (int k = 0; k < kKindCount; ++k) {
    const TransitionParams& start = config_.initial_transitions[k];
    const auto& n = sums_.transitions.n[k];
    const double of = (std::max(n[1][0], 0.0) + w * start.p_occ_given_free) / (std::max(n[1][0] + n[1][1], 0.0) + w);
    const double fo = (std::max(n[0][1], 0.0) + w * start.p_free_given_occ) / (std::max(n[0][0] + n[0][1], 0.0) + w);
    transitions_[k] = TransitionParams{std::clamp(of, p_min_, p_max_), std::clamp(fo, p_min_, p_max_)};
    const double lambda = transitions_[k].lambda();
    log_lambda_[k] = lambda > 0.0 ? std::log(lambda) : -INFINITY;
    log_p_of_[k] = std::log(transitions_[k].p_occ_given_free);
    log_p_fo_[k] = std::log(transitions_[k].p_free_given_occ);
    weights_[k] = std::max(sums_.membership[k], 0.0) + config_.weight_prior_cells * config_.initial_weights[k];
    share_total += weights_[k];
  }
  for (double& weight : weights_) weight /= share_total;
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
