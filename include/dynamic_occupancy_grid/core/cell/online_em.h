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

/// Options of online learning. Defaults are for a 1 Hz time step. The statistics are
/// running sums over time steps (step size 1/t from prior_weight pseudo-transitions), every
/// step, observed or not, decayed by 1 - learning_rate_floor (docs/online_learning.md).
struct OnlineEmConfig {
  /// Weight of the prior transition guess, in pseudo-transitions per from-state.
  double prior_weight = 10.0;
  /// Floor of the learning rate: Murphy's decay d = 1 - floor per time step, a memory of
  /// about 1 / floor steps (0 = plain running sums, no forgetting).
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
/// evidence `log_likelihood_ratio`, then the M-step. The filter keeps the prior transitions
/// until the cell has min_observed_steps observed steps.
void onlineLearnStep(OnlineCell& cell, std::int64_t gap, double log_likelihood_ratio,
                     const TransitionParams& prior, const OnlineEmConfig& config);

}  // namespace core
}  // namespace dynamic_occupancy_grid
