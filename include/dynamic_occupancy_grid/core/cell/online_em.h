#pragma once
// Online EM of a cell's transition probabilities (Mongillo & Deneve 2008; THEORY.md §6,
// eq. (13)). Per cell eight statistics S(i, j, m) are carried along with the filter; the
// M-step after every step turns them into the transition probabilities. Steps without an
// observation are applied in closed form (onlineEmSkip), O(1) whatever the gap.
//
// Kernels work in double on one cell; the grid stores the statistics as float.
// ROS-free: standard library only.

#include <array>
#include <cstdint>

#include "dynamic_occupancy_grid/core/cell/cell_model.h"

namespace dynamic_occupancy_grid {
namespace core {

/// S(i, j, m) of THEORY.md §6: the (decayed) sum over past steps tau of
/// p(x_{tau-1} = i, x_tau = j, x_now = m | z_1:now). Index 0 = occ, 1 = free.
struct TransitionStats {
  std::array<double, 8> s{};

  static constexpr int index(int i, int j, int m) { return (i * 2 + j) * 2 + m; }
  double& at(int i, int j, int m) { return s[index(i, j, m)]; }
  double at(int i, int j, int m) const { return s[index(i, j, m)]; }
  /// Expected number of i -> j transitions: sum over m of S(i, j, m).
  double transitions(int i, int j) const { return at(i, j, 0) + at(i, j, 1); }
  /// Sum of all eight: the statistics' total weight.
  double total() const;
};

/// How the statistics weigh the past (THEORY.md §6b; docs/online_learning.md).
enum class StepSchedule {
  /// Running sums over time steps (step size 1/t from prior_weight pseudo-transitions),
  /// every step, observed or not, decayed by 1 - learning_rate_floor. The default: with
  /// the empirical-Bayes prior (MapperConfig::learn_prior) it is the most accurate on the
  /// cells that change in docs/online_learning.md's comparison.
  kHarmonic,
  /// Cappé's schedule per observed step n: gamma_n = max(learning_rate_floor,
  /// (n + step_size_offset)^-step_size_exponent); the statistics are normalised
  /// (S <- (1 - gamma) S r + gamma new), and a gap of unobserved steps before an observed
  /// step counts as one step of weight gamma_n (its steps carry no evidence of their own).
  /// Learns fast cells' rates faster (dynamic_25_25: MAE 0.10 against 0.18), but its short
  /// memory learns some wall cells as changing.
  kRobbinsMonro,
};

/// Options of online learning. Defaults are for a 1 Hz time step.
struct OnlineEmConfig {
  StepSchedule schedule = StepSchedule::kHarmonic;
  /// kRobbinsMonro: alpha in (0.5, 1] and n0 >= 0 of gamma_n = (n + n0)^-alpha.
  double step_size_exponent = 0.6;
  double step_size_offset = 2.0;
  /// Polyak–Ruppert averaging of the M-step's parameters: from observed step
  /// averaging_start on, the cell uses the running mean of the M-step results since then
  /// (0 = no averaging, the M-step's result itself). See onlineLearnStep.
  std::uint32_t averaging_start = 0;
  /// Weight of the prior transition guess: kHarmonic, in pseudo-transitions per from-state;
  /// kRobbinsMonro uses weight 1 per from-state (step_size_offset sets how fast the first
  /// observations replace it).
  double prior_weight = 10.0;
  /// Floor of the learning rate. kHarmonic: Murphy's decay d = 1 - floor per time step, a
  /// memory of about 1 / floor steps (0 = plain running sums, no forgetting).
  /// kRobbinsMonro: the smallest gamma_n, a memory of about 1 / floor observed steps.
  double learning_rate_floor = 1e-3;
  /// Bounds of the learned p_occ_given_free and p_free_given_occ (per step).
  double p_min = 1e-4;
  double p_max = 0.5;
  /// Learn one change probability p_c = p_of = p_fo (Murphy's symmetric model).
  bool symmetric = false;
  /// A cell's filter uses the prior transitions until it has been observed in this many
  /// steps; the statistics are gathered from the first one.
  std::uint32_t min_observed_steps = 10;

  /// Throws std::invalid_argument naming the first bad field.
  void validate() const;
  /// 1 - learning_rate_floor.
  double decay() const { return 1.0 - learning_rate_floor; }
  /// kRobbinsMonro: gamma_n of observed step n >= 1.
  double stepSize(std::uint32_t n) const;
  /// Weight per from-state of the statistics a new cell starts with.
  double initialWeight() const { return schedule == StepSchedule::kHarmonic ? prior_weight : 1.0; }
};

/// Statistics of a cell before its first step: prior_weight pseudo-transitions from each
/// state, split as the prior transitions, with the current state distributed as p_occ.
/// Their M-step gives back `prior`, and their m-marginal is proportional to the belief,
/// which the recursion needs to stay exact.
TransitionStats priorStats(const TransitionParams& prior, double prior_weight, double p_occ);

/// One step with evidence `log_likelihood_ratio` (log p(z|occ)/p(z|free), 0 for none):
/// the recursion of THEORY.md §6 with gamma = 1 - decay, gamma' = 1, using transitions
/// `params` (the ones the filter uses). Updates `stats`; returns p(occ) after the step,
/// which equals filterStep(p_occ, params, log_likelihood_ratio).
double onlineEmStep(TransitionStats& stats, double p_occ, const TransitionParams& params,
                    double log_likelihood_ratio, double decay);

/// `steps` (>= 0) consecutive steps without observation in closed form: exactly what
/// `steps` calls of onlineEmStep with ratio 0 give, at O(1) cost. Returns p(occ) after them.
double onlineEmSkip(TransitionStats& stats, double p_occ, const TransitionParams& params,
                    std::int64_t steps, double decay);

/// kRobbinsMonro's observed step: S <- (1 - gamma) sum_k S(., ., k) r_km + gamma new, with
/// gamma in (0, 1]. Returns p(occ) after the step (filterStep's).
double onlineEmStepWeighted(TransitionStats& stats, double p_occ, const TransitionParams& params,
                            double log_likelihood_ratio, double gamma);

/// kRobbinsMonro's gap: `steps` unobserved steps that together weigh `gamma` in (0, 1]:
/// each step decays the statistics by rho = (1 - gamma)^(1/steps) and adds 1 - rho of its
/// own, so the gap's new statistics sum to gamma and the old ones keep 1 - gamma. O(1).
double onlineEmSkipWeighted(TransitionStats& stats, double p_occ, const TransitionParams& params,
                            std::int64_t steps, double gamma);

/// The M-step: a_ij = sum_m S(i,j,m) / sum_{j,m} S(i,j,m); with `symmetric`, one
/// p_c = (transitions occ->free + free->occ) / all transitions. Clamped to [p_min, p_max].
/// A from-state without weight keeps `fallback`'s value.
TransitionParams onlineMStep(const TransitionStats& stats, const OnlineEmConfig& config,
                             const TransitionParams& fallback);

/// One cell's online learner, in double (the grid stores it as float).
struct OnlineCell {
  double p_occ = 0.5;                ///< belief at the cell's last step
  TransitionStats stats;             ///< S(i, j, m)
  std::uint32_t observed_steps = 0;  ///< steps with an observation so far
  TransitionParams params;           ///< transitions the filter uses now
};

/// A cell about to get its first observation: belief `initial_p_occ` (the step before),
/// prior statistics, prior transitions.
OnlineCell newOnlineCell(const TransitionParams& prior, double initial_p_occ,
                         const OnlineEmConfig& config);

/// The update of a cell observed in a step, as the Mapper runs it: `gap` (>= 0) steps
/// without observation since its last step in closed form, then the observed step with
/// evidence `log_likelihood_ratio`, then the M-step (and the averaging of kRobbinsMonro).
/// The filter keeps the prior transitions until the cell has min_observed_steps observed
/// steps. With averaging_start > 0 the M-step's results from observed step
/// max(averaging_start, min_observed_steps) on are averaged (weight max(1 / count,
/// learning_rate_floor)) into the transitions the filter uses.
void onlineLearnStep(OnlineCell& cell, std::int64_t gap, double log_likelihood_ratio,
                     const TransitionParams& prior, const OnlineEmConfig& config);

}  // namespace core
}  // namespace dynamic_occupancy_grid
