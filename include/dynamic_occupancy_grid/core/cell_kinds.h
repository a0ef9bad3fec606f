#pragma once
// Kinds of cells: a hierarchical prior that the map learns from itself
// (docs/online_learning.md, "Kinds of cells"; THEORY.md §6b's learned prior, made exact).
//
// Places in a building come in a few kinds: walls and free floor that never change, doors
// and parked carts that change every few minutes, spots where people come and go within
// seconds. Each kind k has its own transitions A_k (p_occ_given_free, p_free_given_occ)
// and a share w_k of the map's cells; both are learned from all cells together. A cell's
// kind is a hidden variable of its own: the cell's filter is the exact posterior
// p(kind, state | its observations), 2 x kKindCount numbers, so a cell seen free for a
// minute is "free floor" with the floor's (never changing) transitions, and a spot seen
// occupied, free, occupied is "people" with the rates the map learned from all such spots,
// after a handful of observations instead of thousands.
//
// The model per cell (index s: 0 = occ, 1 = free):
//   kind k ~ w (the population's shares), state x_0 ~ (initial_p_occ, 1 - initial_p_occ);
//   every step, x_t ~ A_k(x_{t-1}, .); observations as in THEORY.md §1;
//   before each observed step the kind is redrawn from w with probability
//   1 - (1 - switch_probability)^(steps since the last observed step), the state kept:
//   places can change what they are (a new door, a moved shelf), and no kind's posterior
//   ever reaches 0.
// Filtering it is exact and O(kKindCount) per observed step; gaps are crossed in closed form
// per kind (THEORY.md §3).
//
// Learning the kinds (population M-step after every applied step):
//   A_k from the expected transitions between consecutive observed steps of all cells,
//     p(kind = k, x_{t-1} = i, x_t = j | z_1:t), plus transition_prior_weight
//     pseudo-transitions per from-state at the kind's initial transitions, all decayed by
//     1 - forgetting per step. (Consecutive steps only: their posterior is exact given the
//     data up to t, so at the true transitions the sums are unbiased; a gap's expected
//     transitions would only repeat the current estimate back to it.)
//   w_k = (sum over cells of p(kind = k | z) + weight_prior_cells * w0_k) / (cells + weight_prior_cells).
//
// ROS-free: standard library only.

#include <array>
#include <cstdint>

#include "dynamic_occupancy_grid/core/cell_model.h"

namespace dynamic_occupancy_grid {
namespace core {

/// Number of kinds. A cell stores its joint posterior in 2 x kKindCount floats.
constexpr int kKindCount = 5;

/// How a cell's kind posterior becomes the two transition probabilities it publishes
/// (the transition layers, the belief layers' prediction, the model file).
enum class KindSummary {
  /// exp(sum_k p(k) log p_k): the posterior mean in log space. A cell 95 % floor and 5 %
  /// people keeps the floor's tiny rates (times 1.4), not a twentieth of the people's.
  kGeometricMean,
  /// sum_k p(k) p_k, the posterior mean.
  kMean,
  /// The rates of the most probable kind.
  kMostProbable,
};

/// Which kinds a cell's transitions teach.
enum class KindCounting {
  /// All, each weighed by the cell's posterior of the kind (plain EM). A cell seen free for
  /// minutes fits every kind whose p_occ_given_free is small about as well as the floor, so
  /// the floor's many cells keep a share of every such kind and drown the few cells that
  /// really change: a kind of fast cells never gets its p_occ_given_free up.
  kPosterior,
  /// Only the cell's most probable kind, with the cell's transitions given that kind
  /// (classification EM): cells the kinds explain equally well go to the biggest.
  kMostProbable,
};

struct KindsConfig {
  /// Where each kind's transitions start, per step. Learned from there; the order has no
  /// meaning to the model.
  std::array<TransitionParams, kKindCount> initial_transitions{
      {{1e-4, 1e-4}, {2e-3, 2e-3}, {0.01, 0.01}, {0.05, 0.05}, {0.25, 0.25}}};
  /// The kinds' shares of the cells before the map has any (sums to 1).
  std::array<double, kKindCount> initial_weights{{0.8, 0.05, 0.05, 0.05, 0.05}};
  /// Weight of the initial transitions in each kind's M-step, in pseudo-transitions per
  /// from-state.
  double transition_prior_weight = 100.0;
  /// Weight of the initial shares, in cells.
  double weight_prior_cells = 100.0;
  /// Per step: the chance that a cell's kind is redrawn from the population (see above).
  double switch_probability = 1e-4;
  /// Per applied step, the kinds' transition sums decay by 1 - forgetting (0 = never).
  double forgetting = 1e-3;
  KindSummary summary = KindSummary::kGeometricMean;
  KindCounting counting = KindCounting::kMostProbable;

  /// Throws std::invalid_argument naming the first bad field.
  void validate() const;
};

/// p(kind = k, x = s | z) of one cell at its last observed step, at index 2k + s.
struct KindJoint {
  std::array<double, 2 * kKindCount> p{};
  double kind(int k) const { return p[2 * k] + p[2 * k + 1]; }
  /// p(occ) = sum_k p(k, occ).
  double occupancy() const;
};

/// Expected transitions i -> j per kind, [k][i][j] (0 = occ, 1 = free).
struct KindTransitions {
  double n[kKindCount][2][2] = {};
};



/// The population: the kinds' transitions and shares and the sums they are learned from.
class CellKinds {
 public:
  /// Throws std::invalid_argument for a bad configuration or bounds (0 < p_min <= p_max <= 0.5).
  CellKinds(const KindsConfig& config, double p_min, double p_max);

  const KindsConfig& config() const { return config_; }
  const TransitionParams& transitions(int k) const { return transitions_[k]; }
  double weight(int k) const { return weights_[k]; }
  /// lambda_k^steps (steps >= 0).
  double lambdaPower(int k, std::int64_t steps) const;


  /// A cell observed for the first time: the population's shares, the state as given.
  KindJoint newCell(double initial_p_occ) const;
  /// Crosses `steps` (>= 0) unobserved steps: each kind's state in closed form (THEORY.md §3).
  void skip(KindJoint& joint, std::int64_t steps) const;
  /// An observed step after `gap` (>= 0) unobserved ones: the kind switch for gap + 1 steps,
  /// one transition, the evidence (log p(z|occ)/p(z|free)). With `transitions` set, adds
  /// p(k, x_{t-1} = i, x_t = j | z_1:t) to it (meant for gap == 0). Returns p(occ).
  double observe(KindJoint& joint, std::int64_t gap, double log_likelihood_ratio, KindTransitions* transitions) const;
  /// p(occ) `steps` (>= 0) steps after the joint's step, exact (a mixture of closed forms).
  double predict(const KindJoint& joint, std::int64_t steps) const;
  /// The cell's two transition probabilities as the configured summary.
  TransitionParams summary(const KindJoint& joint) const;

  /// Learning: a cell's transitions (observe's output), and the change of a cell's kind
  /// posterior (new minus old; a new cell adds its whole posterior and `new_cell`).
  void addTransitions(const KindTransitions& transitions);
  void addMembership(const std::array<double, kKindCount>& delta, bool new_cell);
  /// The M-step after an applied step: decays the transition sums, then recomputes the
  /// kinds' transitions and shares.
  void update();

  /// Everything the kinds are learned from (model files).
  struct Sums {
    KindTransitions transitions;
    std::array<double, kKindCount> membership{};  ///< sum over cells of p(kind | z)
    double cells = 0.0;
  };
  const Sums& sums() const { return sums_; }
  /// Restores saved sums and recomputes. Throws std::invalid_argument for negative or
  /// non-finite values.
  void restore(const Sums& sums);

 private:
  void recompute();

  KindsConfig config_;
  double p_min_;
  double p_max_;
  std::array<TransitionParams, kKindCount> transitions_;
  std::array<double, kKindCount> weights_;
  std::array<double, kKindCount> log_lambda_;  ///< log lambda_k (lambda_k > 0: rates <= 0.5)
  std::array<double, kKindCount> log_p_of_;
  std::array<double, kKindCount> log_p_fo_;
  double log_keep_;  ///< log(1 - switch_probability)
  Sums sums_;
};

}  // namespace core
}  // namespace dynamic_occupancy_grid
