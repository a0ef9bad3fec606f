#include "dynamic_occupancy_grid/core/cell/online_em.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "power_sums.h"

namespace dynamic_occupancy_grid {
namespace core {
namespace {

void require(bool ok, const std::string& message) {
  if (!ok) throw std::invalid_argument(message);
}

// A as a 2x2 array, a[i][j] = p(x_t = j | x_{t-1} = i).
struct Matrix2 {
  double a[2][2];
};

Matrix2 transitionMatrix(const TransitionParams& params) {
  return Matrix2{{{1.0 - params.p_free_given_occ, params.p_free_given_occ},
                  {params.p_occ_given_free, 1.0 - params.p_occ_given_free}}};
}

// Beyond this the likelihood of the other state underflows to 0; both are then certain
// enough that clamping changes nothing but keeps c > 0.
constexpr double kMaxLogLikelihoodRatio = 700.0;

// Gaps up to this many steps are crossed step by step (see onlineEmSkip).
constexpr std::int64_t kShortGap = 6;

}  // namespace

double TransitionStats::total() const {
  double sum = 0.0;
  for (const double value : s) sum += value;
  return sum;
}

void OnlineEmConfig::validate() const {
  require(std::isfinite(prior_weight) && prior_weight >= 0.0,
          "online_em prior_weight must be >= 0, got " + std::to_string(prior_weight));
  require(learning_rate_floor >= 0.0 && learning_rate_floor < 1.0,
          "online_em learning_rate_floor must be in [0, 1), got " + std::to_string(learning_rate_floor));
  require(p_min >= 0.0 && p_max <= 1.0 && p_min <= p_max,
          "online_em bounds need 0 <= p_min <= p_max <= 1, got p_min " + std::to_string(p_min) +
              ", p_max " + std::to_string(p_max));
}

TransitionStats priorStats(const TransitionParams& prior, double prior_weight, double p_occ) {
  const Matrix2 a = transitionMatrix(prior);
  const double q[2] = {p_occ, 1.0 - p_occ};
  TransitionStats stats;
  for (int i = 0; i < 2; ++i) {
    for (int j = 0; j < 2; ++j) {
      for (int m = 0; m < 2; ++m) stats.at(i, j, m) = prior_weight * a.a[i][j] * q[m];
    }
  }
  return stats;
}

double onlineEmStep(TransitionStats& stats, double p_occ, const TransitionParams& params,
                    double log_likelihood_ratio, double decay) {
  const Matrix2 a = transitionMatrix(params);
  // b(z) up to a common factor, the larger one 1: nothing overflows.
  const double ratio = std::clamp(log_likelihood_ratio, -kMaxLogLikelihoodRatio, kMaxLogLikelihoodRatio);
  const double b[2] = {ratio >= 0.0 ? 1.0 : std::exp(ratio), ratio >= 0.0 ? std::exp(-ratio) : 1.0};
  const double q[2] = {p_occ, 1.0 - p_occ};
  // THEORY.md §6: c = sum_{k,m} q(k) a_km b_m, r_km = a_km b_m / c.
  double r[2][2];
  double c = 0.0;
  for (int k = 0; k < 2; ++k) {
    for (int m = 0; m < 2; ++m) {
      r[k][m] = a.a[k][m] * b[m];
      c += q[k] * r[k][m];
    }
  }
  for (auto& row : r) {
    for (double& value : row) value /= c;
  }
  TransitionStats next;
  for (int i = 0; i < 2; ++i) {
    for (int j = 0; j < 2; ++j) {
      for (int m = 0; m < 2; ++m) {
        const double carried = stats.at(i, j, 0) * r[0][m] + stats.at(i, j, 1) * r[1][m];
        next.at(i, j, m) = decay * carried + (j == m ? q[i] * r[i][j] : 0.0);
      }
    }
  }
  stats = next;
  return q[0] * r[0][0] + q[1] * r[1][0];
}

double onlineEmSkip(TransitionStats& stats, double p_occ, const TransitionParams& params,
                    std::int64_t steps, double decay) {
  if (steps <= 0) return p_occ;
  // A short gap is cheaper step by step (about 16 multiply-adds a step) than the closed form
  // (a handful of pow/expm1 calls).
  if (steps <= kShortGap) {
    const Matrix2 a = transitionMatrix(params);
    double q[2] = {p_occ, 1.0 - p_occ};
    for (std::int64_t step = 0; step < steps; ++step) {
      // A none step: b = 1, c = 1, r = A.
      TransitionStats next;
      for (int i = 0; i < 2; ++i) {
        for (int j = 0; j < 2; ++j) {
          for (int m = 0; m < 2; ++m) {
            const double carried = stats.at(i, j, 0) * a.a[0][m] + stats.at(i, j, 1) * a.a[1][m];
            next.at(i, j, m) = decay * carried + (j == m ? q[i] * a.a[i][j] : 0.0);
          }
        }
      }
      stats = next;
      const double q_occ = q[0] * a.a[0][0] + q[1] * a.a[1][0];
      q[0] = q_occ;
      q[1] = 1.0 - q_occ;
    }
    return q[0];
  }
  // A^n = Pi + lambda^n D with Pi's rows = pi and D = I - Pi. For a static cell any pi
  // works (lambda = 1 makes A^n = Pi + D = I); take (1/2, 1/2).
  const double change_sum = params.p_occ_given_free + params.p_free_given_occ;
  const double pi_occ = change_sum > 0.0 ? params.p_occ_given_free / change_sum : 0.5;
  const double pi[2] = {pi_occ, 1.0 - pi_occ};
  const double lambda = params.lambda();
  const double floor = 1.0 - decay;
  const double delta[2] = {p_occ - pi[0], -(p_occ - pi[0])};  // q - pi
  const Matrix2 a = transitionMatrix(params);

  // Per (i, j), k none steps give (THEORY.md §6 with b = 1, c = 1, r = A):
  //   s_ij <- rho^k s_ij A^k + a_ij sum_{l<k} rho^l q_{k-1-l}(i) e_j A^l,
  // with q_n = pi + lambda^n delta and e_j A^l = pi + lambda^l (e_j - pi), which sums to
  //   a_ij [ pi_i pi G(rho) + pi_i (e_j - pi) G(rho lambda)
  //          + delta_i pi M(rho, lambda) + delta_i (e_j - pi) lambda^(k-1) G(rho) ],
  // G(x) = sum_{l<k} x^l and M(rho, lambda) = sum_{l<k} rho^l lambda^(k-1-l).
  const double rho_k = std::pow(decay, static_cast<double>(steps));
  const double lambda_k = lambdaPower(params, steps);
  const double lambda_k1 = lambdaPower(params, steps - 1);
  const double g_rho = detail::geometricSum(decay, floor, steps);
  // 1 - rho lambda = floor + rho (p_of + p_fo), without cancellation near 1.
  const double g_rho_lambda = detail::geometricSum(decay * lambda, floor + decay * change_sum, steps);
  // rho - lambda = (p_of + p_fo) - floor.
  const double m_rho_lambda = detail::mixedPowerSum(decay, lambda, change_sum - floor, steps);

  for (int i = 0; i < 2; ++i) {
    for (int j = 0; j < 2; ++j) {
      const double total = stats.transitions(i, j);
      for (int m = 0; m < 2; ++m) {
        const double d_jm = (j == m ? 1.0 : 0.0) - pi[m];
        // s_ij A^k = (sum_m s_ij) pi + lambda^k (s_ij - (sum_m s_ij) pi).
        const double carried = total * pi[m] + lambda_k * (stats.at(i, j, m) - total * pi[m]);
        const double added = pi[i] * pi[m] * g_rho + pi[i] * d_jm * g_rho_lambda +
                             delta[i] * pi[m] * m_rho_lambda + delta[i] * d_jm * lambda_k1 * g_rho;
        stats.at(i, j, m) = rho_k * carried + a.a[i][j] * added;
      }
    }
  }
  return pi[0] + lambda_k * delta[0];
}

TransitionParams onlineMStep(const TransitionStats& stats, const OnlineEmConfig& config,
                             const TransitionParams& fallback) {
  const auto bounded = [&](double p) { return std::clamp(p, config.p_min, config.p_max); };
  const double from_occ = stats.transitions(0, 0) + stats.transitions(0, 1);
  const double from_free = stats.transitions(1, 0) + stats.transitions(1, 1);
  if (config.symmetric) {
    const double all = from_occ + from_free;
    if (!(all > 0.0)) return fallback;
    const double p_change = bounded((stats.transitions(0, 1) + stats.transitions(1, 0)) / all);
    return TransitionParams{p_change, p_change};
  }
  TransitionParams params = fallback;
  if (from_free > 0.0) params.p_occ_given_free = bounded(stats.transitions(1, 0) / from_free);
  if (from_occ > 0.0) params.p_free_given_occ = bounded(stats.transitions(0, 1) / from_occ);
  return params;
}

OnlineCell newOnlineCell(const TransitionParams& prior, double initial_p_occ,
                         const OnlineEmConfig& config) {
  OnlineCell cell;
  cell.p_occ = initial_p_occ;
  cell.stats = priorStats(prior, config.prior_weight, initial_p_occ);
  cell.observed_steps = 0;
  cell.params = prior;
  return cell;
}

void onlineLearnStep(OnlineCell& cell, std::int64_t gap, double log_likelihood_ratio,
                     const TransitionParams& prior, const OnlineEmConfig& config) {
  const double decay = config.decay();
  if (gap > 0) cell.p_occ = onlineEmSkip(cell.stats, cell.p_occ, cell.params, gap, decay);
  cell.p_occ = onlineEmStep(cell.stats, cell.p_occ, cell.params, log_likelihood_ratio, decay);
  if (cell.observed_steps < std::numeric_limits<std::uint32_t>::max()) ++cell.observed_steps;
  if (cell.observed_steps < config.min_observed_steps) {
    cell.params = prior;
    return;
  }
  cell.params = onlineMStep(cell.stats, config, cell.params);
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
