#pragma once
// Murphy's 1D corridor (K. P. Murphy, "Bayesian map learning in dynamic environments",
// NIPS 1999, Sections 2–4; ../shared/papers/murphy-1999-*), reproduced: the model, the
// robot's path with the slip of his Section 3, and four estimators of
// p(L_t, M_t | y_{1:t}) (L_t the robot's cell, M_t the map, y_t = (z_t, a_t)):
//   exact Bayes   enumeration over maps x positions (2^N N states: N = 8 gives 2048)
//   online EM     the map as a parameter, fixed-lag smoothing, exponential forgetting
//   offline EM    Baum–Welch over positions given the map, M-step for the map, iterated
//   RBPF          particles sample the position trajectory; each carries per-cell map
//                 posteriors (the core's cell HMM, predicted across gaps in closed form)
// and the experiment that scores them against the exact posterior (docs/murphy_corridor.md).
//
// Indexing: time t and cells are 0-based here; the paper's (and the CSV files') are 1-based,
// so the paper's t = 5, cell 4 is index 4, cell 3 here.
//
// Labels: a cell's value is 0 or 1 (the paper's "off"/"on", white/black). In the core's cell
// HMM, label 1 plays "occupied" and an observation z = 1 a hit: p(hit | occ) = p_o,
// p(hit | free) = 1 - p_o, and a symmetric change p_c both ways.
//
// ROS-free: standard library and the core only.

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include "dynamic_occupancy_grid/core/cell/cell_model.h"
#include "dynamic_occupancy_grid/evaluation/simulator.h"

namespace dynamic_occupancy_grid {
namespace evaluation {

/// The model of Murphy's Section 2 on a corridor of `cells` cells.
struct CorridorModel {
  int cells = 8;               ///< N_L; the paper's Fig. 1(b) corridor has 8
  double p_action = 0.8;       ///< p_a: a move succeeds; else the wheels slip and the robot stays
  double p_observation = 0.9;  ///< p_o: z_t is the current cell's label; else the other label
  double p_change = 0.0;       ///< p_c: a cell's label flips per step (0 in Section 3: static)

  /// The cell HMM of one cell in the core's terms (label 1 = occ): p_c both ways.
  core::TransitionParams cellTransitions() const { return core::TransitionParams{p_change, p_change}; }
  /// The core's sensor model for z: p(z = 1 | label 1) = p_o, p(z = 1 | label 0) = 1 - p_o.
  core::ObservationModel observationModel() const { return core::ObservationModel(p_observation, 1.0 - p_observation); }
  /// Throws std::invalid_argument naming the first bad field: cells in [2, 30], p_a in
  /// [0, 1], p_o in (0.5, 1), p_c in [0, 0.5].
  void validate() const;
};

/// Murphy's Section 3 model: 8 cells, p_o = 0.9, p_a = 0.8, p_c = 0.
CorridorModel murphyModel();

enum class Move : std::uint8_t { kLeft = 0, kRight = 1 };

/// One run: the actions taken, what the robot saw, and (for scoring only) the truth.
struct CorridorEpisode {
  /// actions[t]: A_t, the action chosen just before step t; actions[0] is not used (the
  /// robot starts in the left-most cell whatever it does, the paper's delta prior).
  std::vector<Move> actions;
  std::vector<std::uint8_t> observations;  ///< z_t in {0, 1}
  std::vector<int> positions;              ///< true L_t (0-based cell)
  std::vector<std::uint32_t> maps;         ///< true M_t, bit i = label of cell i

  std::size_t steps() const { return observations.size(); }
  /// Throws std::invalid_argument unless the vectors have one entry per step (at least
  /// one), labels are 0/1, positions are cells of `model` and maps fit in its cells.
  void validate(const CorridorModel& model) const;
};

/// The paper's run (Section 3, the table before Fig. 2): 16 steps on the 8-cell corridor
/// whose true map is 01010101 (cell 1 = 0, cell 2 = 1, ...; the paper's "map 171" in
/// MATLAB's 1-based numbering of the 256 maps, bit 0 = cell 1), the robot starting in cell 1,
/// trying to move right at t = 2..9 and left at t = 10..16. One slip: the move right after
/// t = 4 fails, so L_4 = L_5 = 4; every other move succeeds (the last right move, at t = 9,
/// reaches cell 8). Every observation is correct:
///   t    1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16
///   L_t  1 2 3 4 4 5 6 7 8  7  6  5  4  3  2  1
///   Z_t  0 1 0 1 1 0 1 0 1  0  1  0  1  0  1  0
/// (The paper's action row is garbled in our copy of the text; the actions are the ones the
/// path and the text imply: "at t = 8 the robot thinks it is in cell 8 ... when it tries to
/// move right, it knows it will remain in cell 8".)
CorridorEpisode murphyEpisode();
/// Its actions: right at t = 2..9 (indices 1..8), left at t = 10..16 (indices 9..15).
std::vector<Move> murphyActions();

/// A run drawn from `model` with the given actions: the initial map uniform over the 2^N
/// maps, the robot in cell 0, each step the move (p_a), the map's flips (p_c per cell), then
/// the observation (p_o). Reproducible from `seed`.
CorridorEpisode simulateCorridor(const CorridorModel& model, const std::vector<Move>& actions, std::uint64_t seed);

/// Pr(L_t = to | L_{t-1} = from, A_t = move) (Section 2): the move succeeds with p_a unless
/// the robot is already at the end it moves towards, where it stays with probability 1.
double positionTransition(const CorridorModel& model, int from, int to, Move move);
/// Pr(Z_t = z | the robot's cell has `label`): p_o if they agree, 1 - p_o otherwise.
double observationLikelihood(const CorridorModel& model, std::uint8_t z, std::uint8_t label);

/// An estimate of the marginals of p(L_t, M_t | evidence) per step, [t][cell].
struct CorridorPosterior {
  std::vector<std::vector<double>> position;  ///< p(L_t = cell)
  /// p(M_t(cell) = 1); empty for an estimator without a map (dead reckoning).
  std::vector<std::vector<double>> map_one;
};

/// The largest corridor exactCorridorPosterior enumerates (2^12 maps x 12 cells).
constexpr int kMaxExactCorridorCells = 12;

/// Exact Bayes (the paper's junction tree result) by enumeration over the 2^N N joint states
/// (map, position): a forward pass (filtering) and a backward pass (smoothing).
struct ExactCorridorPosterior {
  CorridorPosterior filtered;  ///< p(. | y_{1:t})
  CorridorPosterior smoothed;  ///< p(. | y_{1:T}), T the episode's length
  /// p(M_t = map | y_{1:t}) over the 2^N maps (bit i = cell i): the paper's Fig. 2(a).
  std::vector<std::vector<double>> maps;
  double log_likelihood = 0.0;  ///< log p(z_{1:T} | a_{1:T})
};
/// Throws std::invalid_argument for an invalid model or episode, or more than
/// kMaxExactCorridorCells cells.
ExactCorridorPosterior exactCorridorPosterior(const CorridorModel& model, const CorridorEpisode& episode);

/// The position predicted from the actions alone (the paper's Fig. 3(b): ignoring the map).
CorridorPosterior deadReckoning(const CorridorModel& model, const CorridorEpisode& episode);

/// Online EM with the map as a parameter (Section 3). The parameter is the observation
/// matrix B(i, k) = Pr(Z = k | L = i; M); with p_o known, B(i, 1) = p_o m_i + (1 - p_o)(1 - m_i)
/// for the map's value m_i = Pr(M(i) = 1) in [0, 1], so the M-step is the constrained
/// maximum: the fraction of ones among the expected counts, clamped to [1 - p_o, p_o].
struct CorridorOnlineEmConfig {
  /// W: the E-step smooths steps [t - W, t] with forward–backward, from the smoothed
  /// L_{t-W-1 | t-1} as the prior. Negative: the paper's maximal window W_t = t (the whole
  /// past, from the known prior); 0: no smoothing (filtering only).
  int window = -1;
  /// d in (0, 1): the expected sufficient statistics are S_t = theta_t + d S_{t-1}, the
  /// paper's "theta_t + d x theta_{t-1}" read recursively (exponential forgetting).
  double decay = 0.5;
  void validate() const;
};
/// position[t]: L_{t|t}, the E-step's filtered marginal at t (with the map of step t - 1);
/// map_one[t]: the map parameter m after step t's M-step (0.5 for a cell without counts).
CorridorPosterior corridorOnlineEm(const CorridorModel& model, const CorridorEpisode& episode,
                                   const CorridorOnlineEmConfig& config);

/// Offline EM (Baum–Welch with the map as the parameter, the constrained M-step of online EM),
/// started from the uninformative map (m = 0.5: the first E-step is dead reckoning).
struct CorridorOfflineEmConfig {
  int max_iterations = 200;
  double tolerance = 1e-10;  ///< stop when the log-likelihood rises by less
  void validate() const;
};
struct CorridorOfflineEmResult {
  /// position[t]: p(L_t | y_{1:T}; m) with the final map; map_one[t]: the final map (the
  /// same at every t: the map is static in EM's model).
  CorridorPosterior smoothed;
  std::vector<double> log_likelihood;  ///< before the first M-step and after each one
  int iterations = 0;                  ///< M-steps
};
/// Offline EM on steps [0, last] of the episode (the whole episode if last < 0).
CorridorOfflineEmResult corridorOfflineEm(const CorridorModel& model, const CorridorEpisode& episode,
                                          const CorridorOfflineEmConfig& config, int last = -1);
/// Offline EM on every prefix y_{1:t}: position[t] = p(L_t | y_{1:t}; m_t), map_one[t] = m_t,
/// m_t the map EM learns from y_{1:t} (the paper's Fig. 2(d), one batch run per step).
CorridorPosterior corridorOfflineEmPerStep(const CorridorModel& model, const CorridorEpisode& episode,
                                           const CorridorOfflineEmConfig& config);

/// core::residualResample (Liu & Chen's residual resampling) with `rng`'s uniform draws.
std::vector<std::size_t> residualResample(const std::vector<double>& weights, std::size_t count, Rng& rng);

/// The RBPF's proposal for L_t (Section 4).
enum class CorridorProposal {
  kTransition,  ///< Pr(L_t | L_{t-1}, a_t); incremental weight p(z_t | L_t, particle's map)
  kOptimal,     ///< Pr(L_t | L_{t-1}, a_t, z_t); incremental weight p(z_t | L_{t-1}, particle's map)
};
struct CorridorRbpfConfig {
  int particles = 50;  ///< the paper's 50
  /// Resample (residual) when N_eff = 1 / sum w_i^2 falls below this fraction of the
  /// particles; 1 resamples at every step whose weights are not all equal (as Murphy does).
  double resample_below = 0.5;
  CorridorProposal proposal = CorridorProposal::kTransition;
  std::uint64_t seed = 1;
  void validate() const;
};
struct CorridorRbpfResult {
  /// position[t] = sum_j w_j [L_t^(j) = cell]; map_one[t] = sum_j w_j p^(j)(M_t(cell) = 1),
  /// with the weights after step t's update and before its resampling.
  CorridorPosterior filtered;
  std::vector<double> effective_sample_size;  ///< N_eff per step, before resampling
  std::vector<std::uint8_t> resampled;        ///< 1 where step t resampled
};
/// The Rao-Blackwellised particle filter of Section 4. Each particle is a trajectory's last
/// cell and, per corridor cell, p(M(i) = 1) at the step it was last updated; the cell HMM of
/// the core predicts it across the gap in closed form (predictOccupancy), the observation
/// updates it (bayesUpdate with the core's sensor model). Reproducible from config.seed.
CorridorRbpfResult corridorRbpf(const CorridorModel& model, const CorridorEpisode& episode,
                                const CorridorRbpfConfig& config);

/// Total variation distance (1/2) sum |p_i - q_i| of two distributions of the same size.
double totalVariation(const std::vector<double>& p, const std::vector<double>& q);

/// The empirical distribution of `count` independent draws from `p` (the yardstick for a
/// particle filter of `count` particles).
std::vector<double> sampleHistogram(const std::vector<double>& p, std::size_t count, Rng& rng);

/// The estimators scored by the experiment.
enum class CorridorEstimator {
  kExact,                ///< exact Bayes itself (error 0; its mass on the true cell)
  kDeadReckoning,        ///< no map (Fig. 3(b))
  kOnlineEm,             ///< maximal window (Figs. 2(c), 3(c))
  kOnlineEmNoSmoothing,  ///< window 0
  kOfflineEm,            ///< one batch EM per prefix y_{1:t} (Fig. 2(d))
  kOfflineEmSmoothed,    ///< batch EM on the whole run, smoothed; scored against exact smoothing
  kRbpf,                 ///< 50 particles, transition proposal (Fig. 4(a-b))
  kRbpfOptimal,          ///< the same with the optimal proposal
};
constexpr std::array<CorridorEstimator, 8> kAllCorridorEstimators{
    CorridorEstimator::kExact,     CorridorEstimator::kDeadReckoning,     CorridorEstimator::kOnlineEm,
    CorridorEstimator::kOnlineEmNoSmoothing, CorridorEstimator::kOfflineEm, CorridorEstimator::kOfflineEmSmoothed,
    CorridorEstimator::kRbpf,      CorridorEstimator::kRbpfOptimal};
/// "exact", "dead_reckoning", "online_em", "online_em_no_smoothing", "offline_em", "offline_em_smoothed",
/// "rbpf", "rbpf_optimal".
const char* corridorEstimatorName(CorridorEstimator estimator);

/// One estimator on one run against the exact posterior (filtered; smoothed for
/// kOfflineEmSmoothed), per step.
struct CorridorErrors {
  std::vector<double> position_tv;  ///< TV distance of p(L_t) to the exact one
  std::vector<double> truth_mass;   ///< p(L_t = the true L_t)
  /// mean over cells of |p(M_t(i) = 1) - exact|; empty without a map (dead reckoning)
  std::vector<double> map_error;
  /// mean over cells of |p(M_t(i) = 1) - [true M_t(i) = 1]|; empty without a map
  std::vector<double> map_truth_error;
};
/// Scores `estimate` against `exact` (the matching one of filtered / smoothed) and the truth.
CorridorErrors scoreCorridor(const CorridorPosterior& estimate, const CorridorPosterior& exact,
                             const CorridorEpisode& episode);

struct MurphyExperimentConfig {
  /// Runs: RBPF seeds on the paper's run, and simulated runs of each variant (one RBPF seed
  /// each).
  int repetitions = 100;
  std::uint64_t seed = 1;  ///< run r's seeds are derived from (seed, r)
  unsigned threads = 0;    ///< runs in parallel; 0 = one per core
  CorridorRbpfConfig rbpf;  ///< particles, resampling; its seed is replaced per run
  CorridorOnlineEmConfig online_em;
  CorridorOfflineEmConfig offline_em;
  /// p_c of the dynamic variant (the same corridor, actions and p_o, p_a; cells change).
  double dynamic_p_change = 0.05;
  /// The particle counts of the sweep on the paper's run (repetitions seeds each).
  std::vector<int> particle_counts{10, 50, 200, 1000};
  void validate() const;
};

/// One variant of the experiment: a model and, per run, every estimator's errors.
struct MurphyVariant {
  std::string name;  ///< "paper", "simulated_static", "simulated_dynamic"
  CorridorModel model;
  /// runs[r][e]: estimator kAllCorridorEstimators[e] on run r.
  std::vector<std::array<CorridorErrors, kAllCorridorEstimators.size()>> runs;
  /// Mean over runs and steps of an estimator's position TV (steps [from, to) of each run,
  /// to < 0: to the end), and of its map error against exact (NaN without a map).
  double meanPositionTv(CorridorEstimator estimator, int from = 0, int to = -1) const;
  double meanTruthMass(CorridorEstimator estimator, int from = 0, int to = -1) const;
  double meanMapError(CorridorEstimator estimator, int from = 0, int to = -1) const;
  /// The largest per-step position TV over runs and steps.
  double maxPositionTv(CorridorEstimator estimator) const;
};

struct MurphyParticleSweepRow {
  int particles = 0;
  std::vector<double> mean_tv;  ///< per seed: the RBPF's position TV averaged over the steps
  std::vector<double> max_tv;   ///< per seed: its largest per-step position TV
  std::vector<double> map_error;  ///< per seed: its map error averaged over the steps
  /// per seed: the position TV of `particles` independent draws from the exact p(L_t | y_{1:t})
  /// itself, averaged over the steps: the Monte Carlo error no filter of that size avoids
  std::vector<double> sampling_floor_tv;
};

struct MurphyExperimentResult {
  CorridorEpisode paper_episode;
  ExactCorridorPosterior paper_exact;
  /// The paper's run, each estimator's estimate (the RBPFs of run 0's seed), in
  /// kAllCorridorEstimators order.
  std::array<CorridorPosterior, kAllCorridorEstimators.size()> paper_estimates;
  std::vector<MurphyVariant> variants;  ///< paper, simulated_static, simulated_dynamic
  std::vector<MurphyParticleSweepRow> particle_sweep;
  double seconds = 0.0;
};

/// The first step of the paper's run's return leg (t = 10, index 9): the robot turns back
/// towards cell 1 (the way back on which online EM gets lost).
constexpr int kMurphyReturnStep = 9;

/// The experiment of docs/murphy_corridor.md: every estimator on Murphy's run (the RBPFs with
/// `repetitions` seeds), and on `repetitions` simulated runs with the paper's actions of the
/// static model and of the dynamic one (p_c = dynamic_p_change), each scored against exact
/// Bayes; the RBPF's error against the number of particles. Results do not depend on the
/// number of threads. `progress` (optional) is called after each run.
MurphyExperimentResult runMurphyExperiment(const MurphyExperimentConfig& config,
                                           const std::function<void(int done)>& progress = {});

/// The experiment's tables for `evaluate` as (file name, CSV text), 1-based t and cells as
/// in the paper:
///   murphy_corridor_fig2_maps.csv      exact p(M_t = map | y_{1:t}) over the 2^8 maps (Fig. 2(a))
///   murphy_corridor_fig2_cells.csv     p(M_t(cell) = 1): exact, online EM, offline EM, RBPF (Fig. 2(b-d))
///   murphy_corridor_fig3_position.csv  p(L_t = cell): exact, dead reckoning, online EM, ... (Fig. 3(a-c))
///   murphy_corridor_fig4_rbpf.csv      the RBPF's position and map next to exact (Fig. 4(a-b))
///   murphy_corridor_errors.csv         per variant, estimator and step: the errors over the runs
///   murphy_corridor_particles.csv      the RBPF's error against the number of particles
std::vector<std::pair<std::string, std::string>> murphyCsvTables(const MurphyExperimentResult& result);

/// A target of the experiment as `evaluate` lists them: what, the measured value, met.
struct MurphyTarget {
  std::string target;
  std::string measured;
  bool met = false;
};
/// The summary.md section ("## Murphy's 1D corridor ..."); appends the targets to `targets`.
std::string formatMurphySummary(const MurphyExperimentConfig& config, const MurphyExperimentResult& result,
                                std::vector<MurphyTarget>* targets);

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
