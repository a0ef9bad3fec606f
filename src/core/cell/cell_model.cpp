#include "dynamic_occupancy_grid/core/cell/cell_model.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <math.h>  // lgamma_r (POSIX)
#include <stdexcept>
#include <string>

namespace dynamic_occupancy_grid {
namespace core {
namespace {

bool isProbability(double p) { return p >= 0.0 && p <= 1.0; }  // false for NaN

// log Gamma(x) for x > 0. Not std::lgamma: glibc's writes the global signgam, a data race
// between offline EM's worker threads and the node's mapping; lgamma_r returns the sign.
double logGamma(double x) {
  int sign = 0;
  return ::lgamma_r(x, &sign);
}

// ln|lambda| computed without cancellation: for tiny p_of + p_fo, lambda rounds to 1
// but log1p keeps the exact rate (a cell changing once in 1e12 steps still mixes).
double logAbsLambda(const TransitionParams& params) {
  const double sum = params.p_occ_given_free + params.p_free_given_occ;
  return sum <= 1.0 ? std::log1p(-sum) : std::log1p(sum - 2.0);
}

// |lambda|^k. pow is exact where the powers are representable (|lambda| = 1/2 gives exact
// 2^-k, which the mixing time's "<= epsilon" needs); for |lambda| within 1e-3 of 1 the
// log1p form keeps the rate that lambda itself lost to rounding.
double absLambdaPower(const TransitionParams& params, double steps) {
  const double abs_lambda = std::abs(params.lambda());
  if (1.0 - abs_lambda > 1e-3) return std::pow(abs_lambda, steps);
  return std::exp(steps * logAbsLambda(params));
}

}  // namespace

double lambdaPower(const TransitionParams& params, std::int64_t steps) {
  if (steps == 0) return 1.0;
  const double lambda = params.lambda();
  if (lambda == 0.0) return 0.0;
  const double magnitude = absLambdaPower(params, static_cast<double>(steps));
  return (lambda < 0.0 && (steps % 2 != 0)) ? -magnitude : magnitude;
}

bool TransitionParams::isValid() const {
  return isProbability(p_occ_given_free) && isProbability(p_free_given_occ);
}

ObservationModel::ObservationModel(double p_hit_given_occ, double p_hit_given_free, double mixed_step_probability)
    : p_hit_given_occ_(p_hit_given_occ),
      p_hit_given_free_(p_hit_given_free),
      mixed_step_probability_(mixed_step_probability) {
  const auto open_unit = [](double p) { return p > 0.0 && p < 1.0; };
  if (!open_unit(p_hit_given_occ) || !open_unit(p_hit_given_free)) {
    throw std::invalid_argument("sensor model: p_hit_given_occ (" +
                                std::to_string(p_hit_given_occ) + ") and p_hit_given_free (" +
                                std::to_string(p_hit_given_free) + ") must be in (0, 1)");
  }
  if (!(p_hit_given_occ > p_hit_given_free)) {
    throw std::invalid_argument("sensor model: p_hit_given_occ (" +
                                std::to_string(p_hit_given_occ) +
                                ") must be greater than p_hit_given_free (" +
                                std::to_string(p_hit_given_free) + ")");
  }
  if (!(mixed_step_probability >= 0.0 && mixed_step_probability <= 0.5)) {
    throw std::invalid_argument("sensor model: mixed_step_probability must be in [0, 0.5], got " +
                                std::to_string(mixed_step_probability));
  }
  hit_log_odds_ = std::log(p_hit_given_occ / p_hit_given_free);
  miss_log_odds_ = std::log1p(-p_hit_given_occ) - std::log1p(-p_hit_given_free);
  log_hit_[0] = std::log(p_hit_given_occ);
  log_hit_[1] = std::log(p_hit_given_free);
  log_miss_[0] = std::log1p(-p_hit_given_occ);
  log_miss_[1] = std::log1p(-p_hit_given_free);
  log_keep_ = std::log1p(-mixed_step_probability);
  log_mixed_ = std::log(mixed_step_probability);
}

std::array<double, 2> ObservationModel::logLikelihoods(std::uint32_t hits, std::uint32_t misses) const {
  std::array<double, 2> log_p{hits * log_hit_[0] + misses * log_miss_[0], hits * log_hit_[1] + misses * log_miss_[1]};
  if (hits == 0 || misses == 0 || mixed_step_probability_ == 0.0) return log_p;
  const double h = hits;
  const double m = misses;
  // log(eps B(h + 1, m + 1)) = log eps + log h! + log m! - log (h + m + 1)!
  const double mixed = log_mixed_ + logGamma(h + 1.0) + logGamma(m + 1.0) - logGamma(h + m + 2.0);
  for (double& log_state : log_p) {
    // log((1 - eps) e^a + e^c) without overflow or underflow.
    const double a = log_keep_ + log_state;
    const double top = std::max(a, mixed);
    log_state = top + std::log1p(std::exp(std::min(a, mixed) - top));
  }
  return log_p;
}

double predictOneStep(double p_occ, const TransitionParams& params) {
  // q·A, first component: p(occ) keeps with 1 - p_fo, free turns occupied with p_of.
  return p_occ * (1.0 - params.p_free_given_occ) + (1.0 - p_occ) * params.p_occ_given_free;
}

double predictOccupancy(double p_occ, const TransitionParams& params, std::int64_t steps) {
  if (steps <= 0 || params.isStatic()) return p_occ;
  const double pi_occ =
      params.p_occ_given_free / (params.p_occ_given_free + params.p_free_given_occ);
  return pi_occ + lambdaPower(params, steps) * (p_occ - pi_occ);
}

double bayesUpdate(double p_occ, double log_likelihood_ratio) {
  // Certain beliefs stay certain (no finite evidence overturns a zero prior); this also
  // keeps 0 * inf out of the formulas below.
  if (p_occ <= 0.0) return 0.0;
  if (p_occ >= 1.0) return 1.0;
  // Exponentiate only non-positive numbers so nothing overflows.
  if (log_likelihood_ratio >= 0.0) {
    const double free_weight = (1.0 - p_occ) * std::exp(-log_likelihood_ratio);
    return p_occ / (p_occ + free_weight);
  }
  const double occ_weight = p_occ * std::exp(log_likelihood_ratio);
  return occ_weight / (occ_weight + (1.0 - p_occ));
}

double filterStep(double p_occ_prev, const TransitionParams& params,
                  double log_likelihood_ratio) {
  return bayesUpdate(predictOneStep(p_occ_prev, params), log_likelihood_ratio);
}

std::optional<double> stationaryOccupancy(const TransitionParams& params) {
  if (params.isStatic()) return std::nullopt;
  return params.p_occ_given_free / (params.p_occ_given_free + params.p_free_given_occ);
}

std::optional<std::int64_t> mixingTime(double p_occ, const TransitionParams& params,
                                       double epsilon) {
  if (!(epsilon > 0.0 && epsilon < 1.0)) {
    throw std::invalid_argument("mixingTime: epsilon must be in (0, 1), got " +
                                std::to_string(epsilon));
  }
  const std::optional<double> pi_occ = stationaryOccupancy(params);
  if (!pi_occ) return std::nullopt;  // static cell: never approaches anything
  const double delta0 = std::abs(p_occ - *pi_occ);
  if (delta0 <= epsilon) return 0;
  if (params.lambda() == 0.0) return 1;  // A has identical rows: one step reaches pi
  const double log_rate = logAbsLambda(params);
  if (log_rate >= 0.0) return std::nullopt;  // |lambda| = 1: the distance never shrinks
  const auto delta_after = [&](double k) { return delta0 * absLambdaPower(params, k); };
  const double k_real = std::ceil(std::log(epsilon / delta0) / log_rate);
  constexpr double kMaxSteps = static_cast<double>(std::numeric_limits<std::int64_t>::max() / 2);
  if (!(k_real < kMaxSteps)) return std::numeric_limits<std::int64_t>::max();
  // The closed form may be one off where Delta_k is within rounding of epsilon: settle it
  // with the same Delta_k the definition uses.
  double k = std::max(1.0, k_real);
  while (k > 1.0 && delta_after(k - 1.0) <= epsilon) k -= 1.0;
  while (delta_after(k) > epsilon) k += 1.0;
  return static_cast<std::int64_t>(k);
}

double updateLogOdds(double log_odds, double log_likelihood_ratio, const LogOddsClamp& clamp) {
  return std::clamp(log_odds + log_likelihood_ratio, clamp.min_log_odds, clamp.max_log_odds);
}

double logOddsToProbability(double log_odds) {
  // 1 / (1 + e^-l), written so that neither branch overflows.
  if (log_odds >= 0.0) return 1.0 / (1.0 + std::exp(-log_odds));
  const double e = std::exp(log_odds);
  return e / (1.0 + e);
}

double probabilityToLogOdds(double p_occ) { return std::log(p_occ) - std::log1p(-p_occ); }

}  // namespace core
}  // namespace dynamic_occupancy_grid
