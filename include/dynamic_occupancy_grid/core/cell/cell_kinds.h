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
// What a moving laser reads of a place that does not change still changes with where it
// looks from: a 5 cm wall cell is hit from one pose and passed through from the next, a
// little further along the wall or under the pose's error. On a robot driving through a
// building most of what looks like change is that. The model explains it as a switch of the
// state at an observed step (learned, at most view_switch_probability), the same for every
// kind, in proportion to the laser's motion since the cell's last observed step, which costs
// the same after a second as after an hour and which the cell keeps until it is seen again.
// Kinds then differ in what changes with time. One kind is not learned: kind 0, the stable
// kind, does not change between observations at all. A place that changed once and then
// held keeps its new state, and a wall the robot left stays a wall; a place seen occupied,
// free, occupied on revisits minutes apart is one of the learned kinds. Without the switch,
// the kind that held walls and floor learned the floor's fast p_free_given_occ (people
// passing) and walls faded within seconds of being left (docs/online_learning.md, "Views
// that change").
//
// The model per cell (index s: 0 = occ, 1 = free):
//   kind k ~ w (the population's shares), state x_0 ~ (initial_p_occ, 1 - initial_p_occ);
//   every step, x_t ~ A_k(x_{t-1}, .), then at an observed step the state switches with
//   observedStepSwitch (view_switch_probability); observations as in THEORY.md §1;
//   before each observed step the kind is redrawn from w with probability
//   1 - (1 - switch_probability)^(steps since the last observed step), the state kept:
//   places can change what they are (a new door, a moved shelf), and no kind's posterior
//   ever reaches 0.
// Filtering it is exact and O(kKindCount) per observed step; gaps are crossed in closed form
// per kind (THEORY.md §3).
//
// Learning the kinds (population M-step after every applied step):
//   Each observed step of a cell seen before adds the pair (its state at its last observed
//   step, its state now), n steps apart, to the cell's most probable kind, given that kind:
//     p(kind = k, x_last = i, x_now = j | z_1:now)  ∝  f(k, i) (A_k^n S)_ij b_j(z_now),
//   S the observed step's switch,
//   binned by n (gapBin). A_k then maximises the likelihood of its pairs,
//     sum over bins and (i, j) of c_k(n, i, j) log (A_k^n)_ij,
//   plus transition_prior_weight one-step pseudo-pairs per from-state at the kind's start,
//   with (A^n)_ij = pi_j + lambda^n (delta_ij - pi_j) (THEORY.md §3). At the true
//   transitions the pair posteriors are unbiased in sum, whatever the gap, and the robot's
//   visits do not depend on the state. Unlike the expected one-step transitions inside a
//   gap (EM's E-step), a pair does not repeat the current estimate back to it: on a patrol
//   nine steps of ten are gaps, and that echo is what keeps each cell's online EM slow.
//   The sums decay by 1 - forgetting per step.
//   w_k = (sum over cells of p(kind = k | z) + weight_prior_cells * w0_k) / (cells + weight_prior_cells).
//   The stable kind's pairs teach nothing: its transitions stay initial_transitions[0].
//
// ROS-free: standard library only.

#include <array>
#include <cstdint>

#include "dynamic_occupancy_grid/core/cell/cell_model.h"

namespace dynamic_occupancy_grid {
namespace core {

/// Number of kinds. A cell stores its joint posterior in 2 x kKindCount floats.
constexpr int kKindCount = 5;
/// The stable kind: no change between observations, never learned (cell_kinds.h above).
constexpr int kStableKind = 0;

struct KindsConfig {
  /// Where each kind's transitions start, per step. Learned from there, except kind 0's:
  /// kind 0 is the stable kind and keeps them.
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
  /// Per observed step from a new view: where the chance that the cell's state switches
  /// starts and the most it may be, in every kind (observedStepSwitch, viewSwitch: learned
  /// from the stable kind's pairs; none when the laser has not moved): what a moving laser
  /// reads of a place changes with where it looks from (a wall cell read from one pose,
  /// passed through from the next under pose and range error), not with the time since it
  /// last looked (docs/online_learning.md, "Views that change"). In [0, 0.5).
  double view_switch_probability = 0.05;
  /// Per applied step, the kinds' transition sums decay by 1 - forgetting (0 = never).
  double forgetting = 1e-3;

  /// Throws std::invalid_argument naming the first bad field.
  void validate() const;
};

/// p(kind = k, x = s | z) of one cell at its last observed step, at index 2k + s.
struct KindJoint {
  std::array<double, 2 * kKindCount> p{};
  double kind(int k) const { return p[2 * k] + p[2 * k + 1]; }
  /// p(occ) = sum_k p(k, occ).
  double occupancy() const {
    double occ = 0.0;
    for (int k = 0; k < kKindCount; ++k) occ += p[2 * k];
    return occ;
  }
};

/// An observed step's evidence as the two likelihoods p(z|occ), p(z|free) up to a common
/// factor (the larger 1), from log p(z|occ)/p(z|free) clamped to +-700 (beyond that the
/// other state's likelihood underflows). One per cell-step, shared by the filter, the pair
/// and the sensor model's statistics.
struct KindEvidence {
  explicit KindEvidence(double log_likelihood_ratio);
  double occ;
  double free;
};

/// Bins of the pairs' distance n in steps (gapBin): 1 to 16 one each, then four per octave
/// up to 2^31.
constexpr int kGapBins = 16 + 4 * 27;
/// The bin of a pair n >= 1 steps apart, and the distance a bin stands for.
int gapBin(std::int64_t steps);
double gapBinSteps(int bin);



/// The population: the kinds' transitions and shares and the sums they are learned from.
class CellKinds {
 public:
  /// Throws std::invalid_argument for a bad configuration or bounds (0 < p_min <= p_max <= 0.5).
  CellKinds(const KindsConfig& config, double p_min, double p_max);

  const KindsConfig& config() const { return config_; }
  const TransitionParams& transitions(int k) const { return transitions_[k]; }
  double weight(int k) const { return weights_[k]; }
  /// lambda_k^steps (steps >= 0): exp(steps log lambda_k), tabulated per M-step up to
  /// kTabulatedSteps.
  double lambdaPower(int k, std::int64_t steps) const;
  /// The kind's stationary occupancy p_occ_given_free / (p_occ_given_free + p_free_given_occ).
  double stationary(int k) const { return pi_[k]; }
  /// The chances that a cell's state switches at an observed step whose view changed by
  /// `view_change` in [0, 1] since the cell's last observed step (1: a new view; 0: the same
  /// laser pose), from occupied (index 0) and from free (1): viewSwitch() times it. The same
  /// for every kind: how a reading varies with the view is the laser's, not the place's. A
  /// laser that does not move reads every change as the place's.
  std::array<double, 2> observedStepSwitch(double view_change) const {
    return {switch_[0] * view_change, switch_[1] * view_change};
  }
  /// The switches from a new view, from occupied and from free, as learned so far: the
  /// stable kind's pairs (its cells change only by the view) that changed state over all its
  /// pairs from that state, with transition_prior_weight pseudo-pairs at
  /// view_switch_probability, and at most that (recompute()).
  const std::array<double, 2>& viewSwitch() const { return switch_; }
  /// p(x_now = occ | x_then = s) of kind k, `steps` (>= 1) apart with an observation at the
  /// end: `steps` transitions (THEORY.md §3), then the observed step's switch.
  double occupiedAfter(int k, int s, std::int64_t steps, double view_change) const;


  /// A cell observed for the first time: the population's shares, the state as given.
  KindJoint newCell(double initial_p_occ) const;
  /// Crosses `steps` (>= 0) unobserved steps: each kind's state in closed form (THEORY.md §3).
  void skip(KindJoint& joint, std::int64_t steps) const;
  /// An observed step after `gap` (>= 0) unobserved ones: the kind switch for gap + 1 steps,
  /// one transition, the state's switch for a view changed by `view_change` (see
  /// observedStepSwitch), the evidence (log p(z|occ)/p(z|free)). Returns p(occ).
  double observe(KindJoint& joint, std::int64_t gap, double log_likelihood_ratio, double view_change = 1.0) const;
  double observe(KindJoint& joint, std::int64_t gap, const KindEvidence& evidence, double view_change = 1.0) const;
  /// The cell's two transition probabilities (the transition layers, the belief layers'
  /// prediction, the model file): exp(sum_k p(k) log p_k), the posterior mean in log space.
  /// A cell 95 % floor and 5 % people keeps the floor's tiny rates (times 1.4), not a
  /// twentieth of the people's.
  TransitionParams summary(const KindJoint& joint) const;

  /// Learning: a cell's pair (its state at its last observed step, its state now), `steps`
  /// (>= 1) apart, from its joint at the last step and this step's evidence; and the change
  /// of a cell's kind posterior (new minus old; a new cell adds its whole posterior and
  /// `new_cell`).
  void addPair(const KindJoint& last, std::int64_t steps, double log_likelihood_ratio, double view_change = 1.0);
  void addPair(const KindJoint& last, std::int64_t steps, const KindEvidence& evidence, double view_change = 1.0);
  void addMembership(const std::array<double, kKindCount>& delta, bool new_cell);
  /// p(k, x_last = i, x_now = j | z) of a pair at [k][i][j] (addPair's posterior).
  using PairPosterior = std::array<std::array<std::array<double, 2>, 2>, kKindCount>;
  PairPosterior pairPosterior(const KindJoint& last, std::int64_t steps, double log_likelihood_ratio,
                              double view_change = 1.0) const;
  PairPosterior pairPosterior(const KindJoint& last, std::int64_t steps, const KindEvidence& evidence,
                              double view_change = 1.0) const;
  /// A new view_switch_probability (KindsConfig); throws std::invalid_argument (and changes
  /// nothing) outside [0, 0.5).
  void setViewSwitchProbability(double view_switch_probability);
  /// The M-step after an applied step: decays the pair sums, then recomputes the kinds'
  /// transitions (from where they are) and shares.
  void update();

  /// Everything the kinds are learned from (model files).
  struct Sums {
    /// Expected pairs per kind and distance bin, [k][bin][2 i + j] (i: the state then, j now).
    std::array<std::array<std::array<double, 4>, kGapBins>, kKindCount> pairs{};
    std::array<double, kKindCount> membership{};  ///< sum over cells of p(kind | z)
    double cells = 0.0;
  };
  const Sums& sums() const { return sums_; }
  /// Restores saved sums and the kinds' transitions learned from them (the M-step starts
  /// from where the last one ended). Throws std::invalid_argument for negative or non-finite
  /// values or transitions outside the bounds.
  void restore(const Sums& sums, const std::array<TransitionParams, kKindCount>& transitions);

 private:
  void recompute();
  /// f(k, i) (A_k^n)_ij b_j(z) at [k][i][j]: the pair posterior up to its normaliser.
  PairPosterior pairWeights(const KindJoint& last, std::int64_t steps, const KindEvidence& evidence,
                            double view_change) const;
  /// The kind's transitions that maximise its pairs' likelihood, from `start`.
  TransitionParams fitPairs(int k, TransitionParams start) const;

  KindsConfig config_;
  double p_min_;
  double p_max_;
  std::array<TransitionParams, kKindCount> transitions_;
  std::array<double, kKindCount> weights_;
  std::array<double, kKindCount> log_lambda_;  ///< log lambda_k (lambda_k > 0: rates <= 0.5)
  std::array<double, kKindCount> log_p_of_;
  std::array<double, kKindCount> log_p_fo_;
  std::array<double, kKindCount> pi_;  ///< stationary occupancy per kind
  double log_keep_;  ///< log(1 - switch_probability)
  /// Gaps up to this many steps (most of them) read lambda_k^n and the kind switch's keep
  /// (1 - switch_probability)^n from tables computed in the M-step, by the same formulas.
  static constexpr int kTabulatedSteps = 64;
  std::array<std::array<double, kKindCount>, kTabulatedSteps + 1> lambda_powers_;  ///< [n][k]
  std::array<double, kTabulatedSteps + 1> keep_powers_;  ///< [n]
  Sums sums_;
  std::array<double, 2> switch_{};  ///< viewSwitch()
};

}  // namespace core
}  // namespace dynamic_occupancy_grid
