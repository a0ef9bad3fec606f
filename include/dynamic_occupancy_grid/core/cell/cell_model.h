#pragma once
// The per-cell model of THEORY.md §1–3: a 2-state hidden Markov model (index 0 = occ,
// 1 = free) with a fixed sensor model, its filter step, closed-form k-step prediction,
// stationary distribution and mixing time, and the standard log-odds occupancy grid used
// as the static baseline. ROS-free: this header must only include the standard library.

#include <array>
#include <cstdint>
#include <optional>

namespace dynamic_occupancy_grid {
namespace core {

/// Transition probabilities of one cell, per HMM time step (THEORY.md §1).
///   A = [ 1 - p_free_given_occ   p_free_given_occ     ]
///       [ p_occ_given_free       1 - p_occ_given_free ]
struct TransitionParams {
  double p_occ_given_free = 0.0;  ///< p_of = p(x_t = occ | x_{t-1} = free)
  double p_free_given_occ = 0.0;  ///< p_fo = p(x_t = free | x_{t-1} = occ)

  /// Second eigenvalue of A: lambda = 1 - p_of - p_fo, in [-1, 1].
  double lambda() const { return 1.0 - p_occ_given_free - p_free_given_occ; }
  /// A = I: the cell never changes (a standard occupancy grid cell).
  bool isStatic() const { return p_occ_given_free + p_free_given_occ == 0.0; }
  /// Both probabilities in [0, 1].
  bool isValid() const;
};

/// The sensor model shared by all cells: p(hit | occ) and p(hit | free); a miss has
/// p(miss | s) = 1 - p(hit | s); a step without observation carries no evidence.
///
/// Steps whose beams disagree (hits and misses in one step): with mixed_step_probability
/// eps > 0 such a step may also come from a cell the beams only partly cover (a wall's edge
/// under the laser's range noise), whose beams hit at an unknown rate q ~ U(0, 1) whatever
/// the state (docs/online_learning.md, "Steps whose beams disagree"):
///   p(z | s) = (1 - eps) p_s^h (1 - p_s)^m + eps B(h + 1, m + 1),
/// B the Beta function (the sequence's likelihood integrated over q). A step of 3 hits and
/// 7 misses is then weak evidence either way rather than strong evidence for "free". Steps
/// that agree (only hits or only misses) keep the plain likelihoods: an edge cell's pure
/// steps are read as the state they show, and one clear step still turns a cell over.
class ObservationModel {
 public:
  /// Throws std::invalid_argument unless both probabilities are in (0, 1),
  /// p_hit_given_occ > p_hit_given_free (a hit must be evidence for "occupied") and
  /// mixed_step_probability is in [0, 0.5].
  ObservationModel(double p_hit_given_occ, double p_hit_given_free, double mixed_step_probability = 0.0);

  double pHitGivenOcc() const { return p_hit_given_occ_; }
  double pHitGivenFree() const { return p_hit_given_free_; }
  /// log p(hit|occ)/p(hit|free) > 0.
  double hitLogOdds() const { return hit_log_odds_; }
  /// log p(miss|occ)/p(miss|free) < 0.
  double missLogOdds() const { return miss_log_odds_; }
  double mixedStepProbability() const { return mixed_step_probability_; }
  /// Log-likelihood ratio log p(z|occ)/p(z|free) of `hits` hits and `misses` misses
  /// fused in one time step (their likelihoods multiply, THEORY.md §1; a step with both
  /// weighed as above).
  double logLikelihoodRatio(std::uint32_t hits, std::uint32_t misses) const {
    if (hits != 0 && misses != 0 && mixed_step_probability_ > 0.0) {
      const std::array<double, 2> log_p = logLikelihoods(hits, misses);
      return log_p[0] - log_p[1];
    }
    return hits * hit_log_odds_ + misses * miss_log_odds_;
  }
  /// log p(z|occ) and log p(z|free) of `hits` hits and `misses` misses in one step, the
  /// partly covered cell's term included where it applies (offline EM's emissions).
  std::array<double, 2> logLikelihoods(std::uint32_t hits, std::uint32_t misses) const;

 private:
  double p_hit_given_occ_;
  double p_hit_given_free_;
  double mixed_step_probability_;
  double hit_log_odds_;
  double miss_log_odds_;
  double log_hit_[2];   ///< log p(hit | occ), log p(hit | free)
  double log_miss_[2];  ///< log p(miss | occ), log p(miss | free)
  double log_keep_;     ///< log(1 - mixed_step_probability)
  double log_mixed_;    ///< log mixed_step_probability (-inf at 0)
};

/// One prediction step without observation: p(occ at t+1) from p(occ at t), i.e. q·A.
double predictOneStep(double p_occ, const TransitionParams& params);

/// lambda^k (k >= 0) of A's second eigenvalue, with the exact sign for lambda < 0 and the
/// rate kept for |lambda| within rounding of 1 (tiny p_of + p_fo).
double lambdaPower(const TransitionParams& params, std::int64_t steps);

/// Closed-form k-step prediction (THEORY.md §3):
///   p(occ at t+k) = pi(occ) + lambda^k (p(occ at t) - pi(occ)).
/// A static cell keeps its belief. k must be >= 0.
double predictOccupancy(double p_occ, const TransitionParams& params, std::int64_t steps);

/// Bayes update of p(occ) with evidence given as a log-likelihood ratio
/// log p(z|occ)/p(z|free). Exact for beliefs of exactly 0 or 1 and for any finite ratio.
double bayesUpdate(double p_occ, double log_likelihood_ratio);

/// The filter step of THEORY.md §2 (AAAI eq. (5)/(7)): predict one step with A, then
/// update with the step's fused evidence.
double filterStep(double p_occ_prev, const TransitionParams& params,
                  double log_likelihood_ratio);

/// Stationary p(occ) = p_of / (p_of + p_fo); std::nullopt for a static cell, whose
/// long-run state is its current one (pi is undefined).
std::optional<double> stationaryOccupancy(const TransitionParams& params);

/// Mixing time (THEORY.md §3): the smallest k >= 0 with
///   Delta_k = |p(occ at t+k) - pi(occ)| <= epsilon,
/// i.e. ceil(ln(epsilon / Delta_0) / ln|lambda|), and 0 when Delta_0 <= epsilon.
/// std::nullopt when the cell never gets there: a static cell, or |lambda| = 1 with
/// Delta_0 > epsilon. epsilon must be in (0, 1).
std::optional<std::int64_t> mixingTime(double p_occ, const TransitionParams& params,
                                       double epsilon);

/// Clamping bounds of the standard occupancy grid (log-odds of p(occ)).
struct LogOddsClamp {
  double min_log_odds = -2.0;  ///< about p = 0.12
  double max_log_odds = 3.5;   ///< about p = 0.97
};

/// The standard occupancy grid update (the static baseline): log-odds plus the step's
/// evidence, clamped to [min, max] after the step.
double updateLogOdds(double log_odds, double log_likelihood_ratio, const LogOddsClamp& clamp);

/// p(occ) of a log-odds value.
double logOddsToProbability(double log_odds);
/// log(p / (1 - p)); +-inf for p = 1 / 0.
double probabilityToLogOdds(double p_occ);

}  // namespace core
}  // namespace dynamic_occupancy_grid
