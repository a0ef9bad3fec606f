#pragma once
// Offline EM (Baum–Welch) of every cell's transition probabilities over a whole recording
// (THEORY.md §5, eq. (12)). A cell's data is its sequence of observed steps; the runs of
// steps without observation between them are crossed in O(1) with the closed-form powers of
// A, and the expected transition counts inside a run have a closed form too, so the cost
// scales with the number of observed steps, not with the length of the recording.
//
// Convention shared with the Mapper: a cell's chain starts the step before its first
// observation, with p(occ) = initial_p_occ.
//
// ROS-free: standard library only.

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <unordered_map>
#include <vector>

#include "dynamic_occupancy_grid/core/cell/cell_model.h"
#include "dynamic_occupancy_grid/core/cell/mrf.h"
#include "dynamic_occupancy_grid/core/grid/traversal.h"

namespace dynamic_occupancy_grid {
namespace core {

/// The evidence of one cell in one step: counts of hits and misses fused (THEORY.md §1).
struct StepObservation {
  std::int32_t step;
  std::uint16_t hits;
  std::uint16_t misses;
};

/// Per-cell sequences of observed steps, stored compactly (8 bytes per observation plus
/// 16 per cell). Build with SequenceBuilder.
class ObservationSequences {
 public:
  std::size_t cellCount() const { return cells_.size(); }
  std::size_t observationCount() const { return observations_.size(); }
  /// Lattice coordinates of cell `index`.
  CellXY cell(std::size_t index) const { return cells_[index]; }
  /// The observations of cell `index`, steps strictly increasing.
  const StepObservation* begin(std::size_t index) const { return observations_.data() + offsets_[index]; }
  const StepObservation* end(std::size_t index) const { return observations_.data() + offsets_[index + 1]; }
  std::size_t bytes() const;

 private:
  friend class SequenceBuilder;
  std::vector<CellXY> cells_;
  std::vector<std::uint64_t> offsets_{0};  ///< cell i: observations_[offsets_[i], offsets_[i+1])
  std::vector<StepObservation> observations_;
};

/// Gathers observations in one pass over the data (any cell order within a step; steps of
/// a cell non-decreasing) and groups them per cell.
class SequenceBuilder {
 public:
  /// Adds the evidence of cell (x, y) in `step`. Counts of the same cell and step add up
  /// (saturating at 65535). Throws std::invalid_argument if `step` is before the cell's
  /// last added step; the builder is unchanged then.
  void add(std::int32_t x, std::int32_t y, std::int32_t step, std::uint32_t hits,
           std::uint32_t misses);
  std::size_t observationCount() const { return records_.size(); }
  /// Forgets every observation of a step after `step` (a Mapper going back to a checkpoint
  /// whose last applied step is `step`, to map its scans again: CorrectedMapping).
  void dropAfter(std::int32_t step);
  /// Adds every observation of `other`, in the order it got them.
  void append(const SequenceBuilder& other);
  /// Groups the observations per cell (cells in order of first appearance) and empties the
  /// builder.
  ObservationSequences build();

 private:
  struct Record {
    std::uint32_t cell;
    StepObservation observation;
  };
  std::unordered_map<std::uint64_t, std::uint32_t> cell_index_;
  std::vector<CellXY> cells_;
  std::vector<std::uint64_t> last_record_;  ///< per cell: index of its latest record
  std::vector<Record> records_;
};

/// Expected transition counts E[N(i -> j) | z] of one cell (index 0 = occ, 1 = free).
using TransitionCounts = std::array<std::array<double, 2>, 2>;

/// A sum of non-negative numbers kept exactly, in fixed point (units of 2^-32 in 128 bits):
/// the total does not depend on the order of the additions, so sums over parts of the
/// cells (threads, or the blocks of sharded offline EM, docs/sharded_em.md) add up to the
/// whole's bit for bit. Each added value is rounded to the nearest unit (2.3e-10).
class FixedPointSum {
 public:
  /// Adds `value`: finite, >= 0 and below 2^90; anything else throws std::invalid_argument.
  void add(double value);
  void add(const FixedPointSum& other) { units_ += other.units_; }
  /// The sum, rounded to the nearest double.
  double value() const;
  /// The count of units as two 64-bit halves, and back (for files).
  std::uint64_t high() const { return static_cast<std::uint64_t>(units_ >> 64); }
  std::uint64_t low() const { return static_cast<std::uint64_t>(units_); }
  static FixedPointSum fromHalves(std::uint64_t high, std::uint64_t low);
  bool operator==(const FixedPointSum& other) const { return units_ == other.units_; }

 private:
  __extension__ typedef unsigned __int128 Units;
  Units units_ = 0;
};

/// One forward–backward pass over one cell's sequence with fixed parameters.
struct ForwardBackwardResult {
  TransitionCounts counts{};    ///< expected transitions over all steps of the chain
  double log_likelihood = 0.0;  ///< log p(z_1:T) with the sensor's true likelihoods (ObservationModel::logLikelihoods)
  double final_p_occ = 0.0;     ///< filtered p(occ) at the last observed step
  /// Expected beam ends (hits + misses) and hits in each state (0 = occ, 1 = free) over the
  /// observed steps, from the smoothed state posteriors: the sensor model's E-step.
  std::array<double, 2> expected_trials{};
  std::array<double, 2> expected_hits{};
};

/// The E-step of one cell: scaled forward–backward over observations [begin, end)
/// (non-empty, steps strictly increasing), O(1) per observation whatever the gaps. Both
/// belief components are carried, so beliefs far below 1e-16 keep their relative precision.
/// Runs of up to 16 transitions are crossed step by step, longer ones in closed form; the
/// closed form loses precision only for lambda within about 1e-6 of -1 (p_of and p_fo both
/// near 1: a cell flipping on nearly every step), where counts carry an absolute error of
/// about 1e-16 * L / (1 + lambda) on a run of L steps.
ForwardBackwardResult forwardBackward(const StepObservation* begin, const StepObservation* end,
                                      const ObservationModel& sensor,
                                      const TransitionParams& params, double initial_p_occ);

/// The lowest MRF temperature accepted (OfflineEmConfig::mrf_temperature, other than 0 = off).
constexpr double kMinMrfTemperature = 1e-9;

struct OfflineEmConfig {
  /// p(occ) the step before a cell's first observation (as the Mapper's initial_p_occ).
  double initial_p_occ = 0.5;
  /// Where EM starts.
  TransitionParams initial_params{0.05, 0.05};
  /// Optional MAP prior: prior_weight pseudo-transitions per from-state, split as `prior`
  /// (0 = maximum likelihood).
  TransitionParams prior{0.01, 0.01};
  double prior_weight = 0.0;
  /// Bounds of the learned probabilities (per step).
  double p_min = 1e-4;
  double p_max = 0.5;
  /// Learn one change probability p_c = p_of = p_fo.
  bool symmetric = false;
  /// A cell stops when an iteration gains less than `tolerance` (nats) of objective, or
  /// after max_iterations M-steps; tolerance 0 always runs max_iterations.
  int max_iterations = 100;
  double tolerance = 1e-4;
  /// Worker threads; 0 = one per core. Results do not depend on it.
  unsigned threads = 0;
  /// MRF-smoothed transition maps (Li, Barão & Rato; THEORY.md §7), the temperature T; 0 =
  /// off (plain per-cell EM, the limit T -> infinity). On: the M-step maximises, jointly over
  /// all cells, the expected log-likelihood (with the MAP prior's pseudo-counts) minus
  /// (1 / T) * sum over 8-neighbour pairs of cells (l_c - l_c')^2, for l the logit of
  /// p(occ -> occ) and, separately, of p(free -> free); cells borrow strength from their
  /// neighbours. All cells then iterate together: EM stops when an iteration gains less than
  /// tolerance * cells (nats), or after max_iterations. Not with `symmetric`.
  double mrf_temperature = 0.0;
  /// Learn the shared sensor model too (docs/online_learning.md, "The sensor model"): after
  /// each round of per-cell EM the emission M-step sets p_hit_given_occ / p_hit_given_free
  /// to the expected hits over the expected beam ends of each state, summed over all cells,
  /// and the cells' EM runs again from their transitions; rounds stop when neither
  /// probability moves by more than 1e-4, or after sensor_model_rounds. Each round raises
  /// the likelihood (coordinate ascent). The learned values stay in [sensor_model_p_min,
  /// 1 - sensor_model_p_min], p_hit_given_occ at least 0.05 above p_hit_given_free.
  /// Not with the MRF.
  bool learn_sensor_model = false;
  int sensor_model_rounds = 20;
  double sensor_model_p_min = 0.01;

  /// Throws std::invalid_argument naming the first bad field.
  void validate() const;
};

struct OfflineEmResult {
  /// Per cell, in the order of ObservationSequences.
  std::vector<TransitionParams> params;
  std::vector<double> final_p_occ;          ///< filtered p(occ) at the cell's last observation
  std::vector<std::int32_t> final_step;     ///< the step of that observation
  std::vector<std::uint16_t> iterations;    ///< M-steps the cell used
  /// Objective summed over cells (log-likelihood, plus the log prior if prior_weight > 0):
  /// entry 0 with initial_params, entry k after k M-steps, up to the most iterations any
  /// cell used; a cell that stopped earlier contributes its last value to later entries.
  std::vector<double> objective;
  std::size_t cells_converged = 0;          ///< stopped by the tolerance, not by max_iterations
  /// With the MRF: per M-step, the Newton iterations spent on p(occ -> occ) and on
  /// p(free -> free) (entry k - 1 for M-step k). Empty without.
  std::vector<std::array<int, 2>> mrf_newton_iterations;
  bool cancelled = false;
  /// The sensor model the params belong to: learned with learn_sensor_model, else the given.
  double p_hit_given_occ = 0.0;
  double p_hit_given_free = 0.0;
  /// learn_sensor_model: rounds of per-cell EM run (1 without).
  int sensor_model_rounds = 1;
  /// learn_sensor_model: the sensor model's E-step of the last round, summed over all cells
  /// (expected beam ends and hits per state, 0 = occ); all zero without.
  std::array<double, 2> sensor_trials{};
  std::array<double, 2> sensor_hits{};
  /// The same sums exactly (sensor_trials[s] == sensor_trials_sum[s].value()): sums over
  /// parts of the cells add up to the whole's.
  std::array<FixedPointSum, 2> sensor_trials_sum{};
  std::array<FixedPointSum, 2> sensor_hits_sum{};
};

/// Called now and then (from a worker thread, never concurrently) with cells done / total;
/// return false to cancel the run (the result is then incomplete and marked cancelled).
using OfflineEmProgress = std::function<bool(std::size_t cells_done, std::size_t cells_total)>;

/// Runs EM on every cell of `sequences`, in parallel over cells. The result is the same
/// for any number of threads. Throws std::invalid_argument for a bad config.
OfflineEmResult runOfflineEm(const ObservationSequences& sequences, const ObservationModel& sensor,
                             const OfflineEmConfig& config, const OfflineEmProgress& progress = {});

/// One round of learn_sensor_model's coordinate ascent, the step runOfflineEm repeats:
/// per-cell EM with the sensor model fixed at `sensor`, cell c starting from start[c]
/// (empty `start`: config.initial_params), and the sensor model's E-step at the cells'
/// final transitions in result.sensor_*_sum (and sensor_trials, sensor_hits). The cells are
/// independent: the rounds of parts of the cells give the whole's cells and, added up, its
/// sums (sharded offline EM). Needs config.learn_sensor_model; throws std::invalid_argument
/// for a bad config or a `start` of another size.
OfflineEmResult runOfflineEmRound(const ObservationSequences& sequences, const ObservationModel& sensor,
                                  const OfflineEmConfig& config, const std::vector<TransitionParams>& start,
                                  const OfflineEmProgress& progress = {});

/// The emission M-step after a round: from the round's sums over all cells, the sensor
/// model the next round uses (each state's expected hits over its expected beam ends, in
/// [sensor_model_p_min, 1 - sensor_model_p_min]); std::nullopt when the rounds stop there:
/// a hit would no longer be evidence for "occupied" (p_hit_given_occ < p_hit_given_free +
/// 0.05), or neither probability moved by more than 1e-4 from `used`, the round's model.
std::optional<ObservationModel> nextSensorModel(const std::array<FixedPointSum, 2>& trials,
                                                const std::array<FixedPointSum, 2>& hits,
                                                const ObservationModel& used, const OfflineEmConfig& config);

/// The E-step of every cell with fixed parameters (params[c] for cell c), in parallel over
/// cells: what one iteration of the MRF's EM computes before its joint M-step. The result
/// does not depend on `threads` (0 = one per core). Throws std::invalid_argument for a
/// `params` of another size.
struct OfflineEStep {
  std::vector<TransitionCounts> counts;
  std::vector<double> log_likelihood;
  std::vector<double> final_p_occ;
};
OfflineEStep offlineEStep(const ObservationSequences& sequences, const ObservationModel& sensor,
                          const std::vector<TransitionParams>& params, double initial_p_occ, unsigned threads);

/// The MRF-smoothed EM's state and joint M-step (OfflineEmConfig::mrf_temperature > 0):
/// the cells in a fixed order, their 8-neighbour graph, the two maps' logits and the cells'
/// current transitions. runOfflineEm alternates offlineEStep and mStep on it; sharded
/// offline EM runs the E-steps per block elsewhere and the M-step here, with the cells in
/// the single process's order, for the same bits (docs/sharded_em.md).
class MrfEm {
 public:
  /// `cells` distinct, in the order of ObservationSequences. Throws std::invalid_argument for
  /// a bad config, mrf_temperature 0 or a repeated cell.
  MrfEm(std::vector<CellXY> cells, const OfflineEmConfig& config);
  std::size_t cellCount() const { return cells_; }
  /// The transitions per cell: initial_params, then each M-step's.
  const std::vector<TransitionParams>& params() const { return params_; }
  const std::vector<double>& logitOcc() const { return logit_occ_; }    ///< logit p(occ -> occ)
  const std::vector<double>& logitFree() const { return logit_free_; }  ///< logit p(free -> free)
  /// Continues from a saved state (params, logits as the getters give them).
  void restore(std::vector<TransitionParams> params, std::vector<double> logit_occ, std::vector<double> logit_free);
  /// The objective EM maximises, for the E-step's log-likelihoods at params().
  double objective(const std::vector<double>& log_likelihood) const;
  /// EM stops after an iteration that gained `gain` (tolerance * cells).
  bool converged(double gain) const;
  /// The joint M-step from the E-step's counts at params(): new logits and params(); the
  /// Newton iterations of each map (p(occ -> occ), p(free -> free)).
  std::array<int, 2> mStep(const std::vector<TransitionCounts>& counts);

 private:
  OfflineEmConfig config_;
  CellNeighbours graph_;
  std::size_t cells_;
  double lo_ = 0.0;
  double hi_ = 0.0;
  std::vector<TransitionParams> params_;
  std::vector<double> logit_occ_;
  std::vector<double> logit_free_;
};

/// The M-step of one cell from its expected counts: row-normalised counts (plus the prior's
/// pseudo-counts), or one symmetric p_c, clamped to [p_min, p_max]. A from-state without
/// weight keeps `previous`'s value.
TransitionParams offlineMStep(const TransitionCounts& counts, const OfflineEmConfig& config,
                              const TransitionParams& previous);

}  // namespace core
}  // namespace dynamic_occupancy_grid
