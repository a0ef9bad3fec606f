#include "dynamic_occupancy_grid/core/cell/offline_em.h"

#include "dynamic_occupancy_grid/core/common/parallel.h"

#include "dynamic_occupancy_grid/core/cell/mrf.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <exception>
#include <limits>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <system_error>
#include <thread>

namespace dynamic_occupancy_grid {
namespace core {
namespace {

void require(bool ok, const std::string& message) {
  if (!ok) throw std::invalid_argument(message);
}

bool isProbability(double p) { return p >= 0.0 && p <= 1.0; }

std::uint16_t saturatingAdd(std::uint32_t a, std::uint32_t b) {
  return static_cast<std::uint16_t>(std::min<std::uint32_t>(a + std::min<std::uint32_t>(b, 65535U), 65535U));
}

// An observation prepared once per cell for all EM iterations: its likelihoods scaled by
// exp(-log_scale) (so hundreds of beams do not underflow) and the number of transitions
// since the previous observation (1 = consecutive steps).
struct Prepared {
  double b_occ;
  double b_free;
  double log_scale;
  std::int64_t length;
  std::uint32_t hits;
  std::uint32_t misses;
};

// Runs up to this many transitions are crossed step by step (exact, and cheaper than the
// closed form's transcendental functions); longer ones in closed form, O(1).
constexpr std::int64_t kShortRun = 16;

// The forward pass multiplies normalisers down to this before taking a log (far from
// underflow: a factor below it is logged on its own).
constexpr double kSmallProduct = 1e-150;

// An observation's likelihoods scaled by the larger one, which becomes exactly 1.
struct ScaledLikelihood {
  double smaller;    // exp(smaller log-likelihood - larger)
  double log_scale;  // the larger log-likelihood
  bool occ_larger;
};

// The step's likelihoods as the sensor model reads them (a step whose beams disagree may
// also come from a partly covered cell: ObservationModel).
ScaledLikelihood scaledLikelihood(std::uint32_t hits, std::uint32_t misses, const ObservationModel& sensor) {
  const std::array<double, 2> log_p = sensor.logLikelihoods(hits, misses);
  const double log_b_occ = log_p[0];
  const double log_b_free = log_p[1];
  const bool occ_larger = log_b_occ >= log_b_free;
  const double scale = occ_larger ? log_b_occ : log_b_free;
  return ScaledLikelihood{std::exp((occ_larger ? log_b_free : log_b_occ) - scale), scale, occ_larger};
}

// The likelihoods of small counts are tabulated as they are met: a cell's observations repeat
// a few (hits, misses) pairs, and MRF EM prepares every cell in every iteration.
constexpr std::uint32_t kTabulatedCounts = 32;

// Per-thread buffers for one sensor, reused from cell to cell.
struct Scratch {
  explicit Scratch(const ObservationModel& sensor)
      : sensor(sensor),
        table(kTabulatedCounts * kTabulatedCounts),
        table_filled(kTabulatedCounts * kTabulatedCounts, 0) {}

  std::vector<Prepared> observations;
  std::vector<std::array<double, 2>> alpha;  // filtered (p(occ), p(free)) after observation k (0: start)
  std::vector<double> normaliser;            // c_k of the scaled forward pass
  std::vector<double> lambda_before;         // lambda^(L_k - 1) of each run
  std::vector<double> objective;             // per iteration, of the cell being run
  ObservationModel sensor;
  // scaledLikelihood(hits, misses) at [hits * kTabulatedCounts + misses], where table_filled.
  std::vector<ScaledLikelihood> table;
  std::vector<char> table_filled;
  // Whether the backward pass also gathers the sensor model's E-step (its cost is only paid
  // where the sensor model is learned).
  bool emissions = true;
};

void prepare(const StepObservation* begin, const StepObservation* end, Scratch& scratch) {
  std::vector<Prepared>& out = scratch.observations;
  out.clear();
  std::int64_t previous = std::int64_t{begin->step} - 1;  // the chain starts the step before
  for (const StepObservation* it = begin; it != end; ++it) {
    ScaledLikelihood b;
    if (it->hits < kTabulatedCounts && it->misses < kTabulatedCounts) {
      const std::size_t key = std::size_t{it->hits} * kTabulatedCounts + it->misses;
      if (!scratch.table_filled[key]) {
        scratch.table[key] = scaledLikelihood(it->hits, it->misses, scratch.sensor);
        scratch.table_filled[key] = 1;
      }
      b = scratch.table[key];
    } else {
      b = scaledLikelihood(it->hits, it->misses, scratch.sensor);
    }
    out.push_back(Prepared{b.occ_larger ? 1.0 : b.smaller, b.occ_larger ? b.smaller : 1.0, b.log_scale,
                           std::int64_t{it->step} - previous, it->hits, it->misses});
    previous = it->step;
  }
}

// A^L with every entry a sum of non-negative products, so that a belief of 1e-30 keeps its
// relative precision through a run (pi + lambda^L (alpha - pi) would keep only 1e-16
// absolute): off-diagonal p_ij (1 - lambda^L) / (p_of + p_fo), diagonal pi_i + lambda^L pi_j
// (or 1 minus the off-diagonal when lambda^L < 0, which needs p_of + p_fo > 1).
struct PowerMatrix {
  double m[2][2];
};

PowerMatrix transitionPower(const TransitionParams& params, double change_sum, double lambda_length,
                            double geometric) {
  // geometric = sum_{n<L} lambda^n = (1 - lambda^L) / (p_of + p_fo), computed by the caller.
  const double to_free = params.p_free_given_occ * geometric;
  const double to_occ = params.p_occ_given_free * geometric;
  PowerMatrix power;
  power.m[0][1] = to_free;
  power.m[1][0] = to_occ;
  if (lambda_length >= 0.0 && change_sum > 0.0) {
    const double pi_occ = params.p_occ_given_free / change_sum;
    const double pi_free = params.p_free_given_occ / change_sum;
    power.m[0][0] = pi_occ + lambda_length * pi_free;
    power.m[1][1] = pi_free + lambda_length * pi_occ;
  } else {
    power.m[0][0] = 1.0 - to_free;
    power.m[1][1] = 1.0 - to_occ;
  }
  return power;
}

// The E-step over prepared observations (THEORY.md §5). Runs of L transitions use
// A^n = Pi + lambda^n D (D = I - Pi); for a static cell any pi works, (1/2, 1/2) is taken.
ForwardBackwardResult forwardBackwardPrepared(Scratch& scratch, const TransitionParams& params,
                                              double initial_p_occ) {
  const std::vector<Prepared>& obs = scratch.observations;
  const std::size_t n = obs.size();
  scratch.alpha.resize(n + 1);
  scratch.normaliser.resize(n);
  scratch.lambda_before.resize(n);

  const double a[2][2] = {{1.0 - params.p_free_given_occ, params.p_free_given_occ},
                          {params.p_occ_given_free, 1.0 - params.p_occ_given_free}};
  const double change_sum = params.p_occ_given_free + params.p_free_given_occ;  // 1 - lambda
  const double lambda = params.lambda();
  const double pi[2] = {change_sum > 0.0 ? params.p_occ_given_free / change_sum : 0.5,
                        change_sum > 0.0 ? params.p_free_given_occ / change_sum : 0.5};
  // sum_{n<L} lambda^n without cancellation for lambda near 1.
  const auto geometricOf = [&](double length, double lambda_length) {
    if (change_sum == 0.0) return length;
    if (change_sum < 1e-3) return -std::expm1(length * std::log1p(-change_sum)) / change_sum;
    return (1.0 - lambda_length) / change_sum;
  };

  ForwardBackwardResult result;
  // Forward: alpha_k = (alpha_{k-1} A^L) o b_k / c_k, both components kept.
  std::array<double, 2> alpha = {initial_p_occ, 1.0 - initial_p_occ};
  scratch.alpha[0] = alpha;
  double product = 1.0;     // of the c_k since the last log taken
  double log_scales = 0.0;  // sum of the observations' log_scale
  for (std::size_t k = 0; k < n; ++k) {
    const Prepared& o = obs[k];
    double predicted[2];
    if (o.length <= kShortRun) {
      predicted[0] = alpha[0];
      predicted[1] = alpha[1];
      for (std::int64_t step = 0; step < o.length; ++step) {
        const double occ = predicted[0] * a[0][0] + predicted[1] * a[1][0];
        const double free = predicted[0] * a[0][1] + predicted[1] * a[1][1];
        predicted[0] = occ;
        predicted[1] = free;
      }
    } else {
      const double lambda_before = lambdaPower(params, o.length - 1);
      scratch.lambda_before[k] = lambda_before;
      const double lambda_length = lambda_before * lambda;
      const PowerMatrix power =
          transitionPower(params, change_sum, lambda_length, geometricOf(static_cast<double>(o.length), lambda_length));
      predicted[0] = alpha[0] * power.m[0][0] + alpha[1] * power.m[1][0];
      predicted[1] = alpha[0] * power.m[0][1] + alpha[1] * power.m[1][1];
    }
    const double u_occ = predicted[0] * o.b_occ;
    const double u_free = predicted[1] * o.b_free;
    const double c = u_occ + u_free;
    alpha = {u_occ / c, u_free / c};
    scratch.normaliser[k] = c;
    scratch.alpha[k + 1] = alpha;
    // log p(z) = sum log c_k + log_scale_k: the c_k (at most 1) are multiplied and their
    // product's log taken only when it gets small, one log per many observations.
    log_scales += o.log_scale;
    if (c < kSmallProduct) {
      result.log_likelihood += std::log(c);
    } else {
      product *= c;
      if (product < kSmallProduct) {
        result.log_likelihood += std::log(product);
        product = 1.0;
      }
    }
  }
  result.log_likelihood += std::log(product) + log_scales;
  result.final_p_occ = alpha[0];

  // Backward with the expected transition counts of each run between observations.
  double beta[2] = {1.0, 1.0};
  for (std::size_t k = n; k-- > 0;) {
    const Prepared& o = obs[k];
    const double c = scratch.normaliser[k];
    const double w[2] = {o.b_occ * beta[0] / c, o.b_free * beta[1] / c};
    if (scratch.emissions) {
      // The smoothed state at this observation, alpha_k o beta_k: the sensor model's E-step.
      const std::array<double, 2>& filtered = scratch.alpha[k + 1];
      const double occ = filtered[0] * beta[0];
      const double p_occ = occ / (occ + filtered[1] * beta[1]);
      const double trials = static_cast<double>(o.hits) + o.misses;
      result.expected_trials[0] += p_occ * trials;
      result.expected_trials[1] += (1.0 - p_occ) * trials;
      result.expected_hits[0] += p_occ * o.hits;
      result.expected_hits[1] += (1.0 - p_occ) * o.hits;
    }
    const std::array<double, 2>& start = scratch.alpha[k];
    if (o.length <= kShortRun) {
      // Step by step: f_n = start A^n forward, g_m = A^m w backward, all products of
      // non-negative numbers (exact to rounding whatever lambda is).
      const std::int64_t length = o.length;
      std::array<std::array<double, 2>, kShortRun> backward;
      backward[0] = {w[0], w[1]};
      for (std::int64_t m = 1; m < length; ++m) {
        const auto& g = backward[m - 1];
        backward[m] = {a[0][0] * g[0] + a[0][1] * g[1], a[1][0] * g[0] + a[1][1] * g[1]};
      }
      std::array<double, 2> f = start;
      for (std::int64_t step = 0; step < length; ++step) {
        const auto& g = backward[length - 1 - step];
        for (int i = 0; i < 2; ++i) {
          for (int j = 0; j < 2; ++j) result.counts[i][j] += a[i][j] * f[i] * g[j];
        }
        f = {f[0] * a[0][0] + f[1] * a[1][0], f[0] * a[0][1] + f[1] * a[1][1]};
      }
      const auto& g = backward[length - 1];
      for (int i = 0; i < 2; ++i) beta[i] = a[i][0] * g[0] + a[i][1] * g[1];
      continue;
    }
    // Over a run of L transitions from `start` to the observation:
    //   E[N_ij] = a_ij sum_{k,l} start_k w_l sum_{n<L} (A^n)_ki (A^(L-1-n))_jl,
    // and with (A^n)_ki = pi_i + lambda^n d_ki, d = I - Pi, the inner sum is
    //   L pi_i pi_l + pi_i d_jl G + d_ki pi_l G + d_ki d_jl L lambda^(L-1),  G = sum_{n<L} lambda^n.
    // Keeping start_k and w_l outside the closed form keeps tiny beliefs exact.
    const double length = static_cast<double>(o.length);
    const double lambda_before = scratch.lambda_before[k];
    const double lambda_length = lambda_before * lambda;
    const double geometric = geometricOf(length, lambda_length);
    const auto d = [&](int row, int col) { return (row == col ? 1.0 : 0.0) - pi[col]; };
    for (int i = 0; i < 2; ++i) {
      for (int j = 0; j < 2; ++j) {
        double sum = 0.0;
        for (int from = 0; from < 2; ++from) {
          for (int to = 0; to < 2; ++to) {
            const double runs = length * pi[i] * pi[to] + pi[i] * d(j, to) * geometric +
                                d(from, i) * pi[to] * geometric +
                                d(from, i) * d(j, to) * length * lambda_before;
            sum += start[from] * w[to] * runs;
          }
        }
        result.counts[i][j] += a[i][j] * sum;
      }
    }
    const PowerMatrix power = transitionPower(params, change_sum, lambda_length, geometric);
    for (int i = 0; i < 2; ++i) beta[i] = power.m[i][0] * w[0] + power.m[i][1] * w[1];
  }
  return result;
}

double logPrior(const TransitionParams& params, const OfflineEmConfig& config) {
  if (config.prior_weight == 0.0) return 0.0;
  const double prior[2][2] = {{1.0 - config.prior.p_free_given_occ, config.prior.p_free_given_occ},
                              {config.prior.p_occ_given_free, 1.0 - config.prior.p_occ_given_free}};
  const double a[2][2] = {{1.0 - params.p_free_given_occ, params.p_free_given_occ},
                          {params.p_occ_given_free, 1.0 - params.p_occ_given_free}};
  double sum = 0.0;
  for (int i = 0; i < 2; ++i) {
    for (int j = 0; j < 2; ++j) {
      const double weight = config.prior_weight * prior[i][j];
      if (weight > 0.0) sum += weight * std::log(a[i][j]);
    }
  }
  return sum;
}

// Cells per unit of parallel work: the partial sums of one chunk are added in cell order
// and chunks in chunk order, so the result does not depend on which thread ran what. The
// size depends on the cell count only (never on the thread count): up to 256 cells, and at
// least 64 chunks where there are enough cells, so small maps still use every core.
std::size_t chunkCells(std::size_t cells) { return std::clamp<std::size_t>(cells / 64, 8, 256); }

}  // namespace

std::size_t ObservationSequences::bytes() const {
  return cells_.size() * sizeof(CellXY) + offsets_.size() * sizeof(std::uint64_t) +
         observations_.size() * sizeof(StepObservation);
}

void SequenceBuilder::add(std::int32_t x, std::int32_t y, std::int32_t step, std::uint32_t hits,
                          std::uint32_t misses) {
  const std::uint64_t key = (std::uint64_t{static_cast<std::uint32_t>(x)} << 32) | static_cast<std::uint32_t>(y);
  const auto found = cell_index_.find(key);
  if (found == cell_index_.end()) {
    const auto index = static_cast<std::uint32_t>(cells_.size());
    records_.push_back(Record{index, StepObservation{step, saturatingAdd(0, hits), saturatingAdd(0, misses)}});
    cell_index_.emplace(key, index);
    cells_.push_back(CellXY{x, y});
    last_record_.push_back(records_.size() - 1);
    return;
  }
  const std::uint32_t index = found->second;
  StepObservation& last = records_[last_record_[index]].observation;
  if (step < last.step) {
    throw std::invalid_argument("SequenceBuilder: step " + std::to_string(step) + " of cell (" +
                                std::to_string(x) + ", " + std::to_string(y) +
                                ") is before its last step " + std::to_string(last.step));
  }
  if (step == last.step) {
    last.hits = saturatingAdd(last.hits, hits);
    last.misses = saturatingAdd(last.misses, misses);
    return;
  }
  records_.push_back(Record{index, StepObservation{step, saturatingAdd(0, hits), saturatingAdd(0, misses)}});
  last_record_[index] = records_.size() - 1;
}

void SequenceBuilder::dropAfter(std::int32_t step) {
  SequenceBuilder kept;
  for (const Record& record : records_) {
    const StepObservation& o = record.observation;
    if (o.step <= step) kept.add(cells_[record.cell].x, cells_[record.cell].y, o.step, o.hits, o.misses);
  }
  *this = std::move(kept);
}

void SequenceBuilder::append(const SequenceBuilder& other) {
  for (const Record& record : other.records_) {
    const StepObservation& o = record.observation;
    add(other.cells_[record.cell].x, other.cells_[record.cell].y, o.step, o.hits, o.misses);
  }
}

ObservationSequences SequenceBuilder::build() {
  ObservationSequences sequences;
  // Counting sort by cell; records of a cell are already in step order.
  sequences.offsets_.assign(cells_.size() + 1, 0);
  for (const Record& record : records_) ++sequences.offsets_[record.cell + 1];
  for (std::size_t i = 0; i < cells_.size(); ++i) sequences.offsets_[i + 1] += sequences.offsets_[i];
  sequences.observations_.resize(records_.size());
  std::vector<std::uint64_t> next(sequences.offsets_.begin(), sequences.offsets_.end() - 1);
  for (const Record& record : records_) sequences.observations_[next[record.cell]++] = record.observation;
  sequences.cells_ = std::move(cells_);
  *this = SequenceBuilder();
  return sequences;
}

ForwardBackwardResult forwardBackward(const StepObservation* begin, const StepObservation* end,
                                      const ObservationModel& sensor,
                                      const TransitionParams& params, double initial_p_occ) {
  if (begin == end) throw std::invalid_argument("forwardBackward: empty sequence");
  Scratch scratch(sensor);
  prepare(begin, end, scratch);
  return forwardBackwardPrepared(scratch, params, initial_p_occ);
}

void OfflineEmConfig::validate() const {
  require(initial_p_occ > 0.0 && initial_p_occ < 1.0,
          "offline_em initial_p_occ must be in (0, 1), got " + std::to_string(initial_p_occ));
  require(initial_params.isValid(), "offline_em initial_params must be probabilities in [0, 1]");
  require(prior.isValid(), "offline_em prior must be probabilities in [0, 1]");
  require(std::isfinite(prior_weight) && prior_weight >= 0.0,
          "offline_em prior_weight must be >= 0, got " + std::to_string(prior_weight));
  require(isProbability(p_min) && isProbability(p_max) && p_min <= p_max,
          "offline_em bounds need 0 <= p_min <= p_max <= 1, got p_min " + std::to_string(p_min) +
              ", p_max " + std::to_string(p_max));
  require(max_iterations >= 0 && max_iterations <= std::numeric_limits<std::uint16_t>::max(),
          "offline_em max_iterations must be in [0, 65535], got " + std::to_string(max_iterations));
  require(std::isfinite(tolerance) && tolerance >= 0.0,
          "offline_em tolerance must be >= 0, got " + std::to_string(tolerance));
  // Below 1e-9 the coupling (2 / T per pair) swamps any evidence by 1e9 and more: the maps
  // are flat to rounding, and the solver's arithmetic degrades.
  require(std::isfinite(mrf_temperature) && (mrf_temperature == 0.0 || mrf_temperature >= kMinMrfTemperature),
          "offline_em mrf_temperature must be 0 (off) or >= 1e-9, got " + std::to_string(mrf_temperature));
  require(!(learn_sensor_model && mrf_temperature > 0.0),
          "offline_em learn_sensor_model does not combine with mrf_temperature > 0");
  require(sensor_model_rounds >= 1 && sensor_model_rounds <= 1000,
          "offline_em sensor_model_rounds must be in [1, 1000], got " + std::to_string(sensor_model_rounds));
  require(sensor_model_p_min > 0.0 && sensor_model_p_min <= 0.4,
          "offline_em sensor_model_p_min must be in (0, 0.4], got " + std::to_string(sensor_model_p_min));
  require(!(symmetric && mrf_temperature > 0.0),
          "offline_em mrf_temperature > 0 does not combine with symmetric: the MRF smooths p(occ -> occ) and "
          "p(free -> free) separately");
}

TransitionParams offlineMStep(const TransitionCounts& counts, const OfflineEmConfig& config,
                              const TransitionParams& previous) {
  const TransitionParams& prior = config.prior;
  const double w = config.prior_weight;
  // Counts plus the prior's pseudo-counts (a Dirichlet prior on each row: MAP-EM).
  const double occ_free = counts[0][1] + w * prior.p_free_given_occ;
  const double occ_occ = counts[0][0] + w * (1.0 - prior.p_free_given_occ);
  const double free_occ = counts[1][0] + w * prior.p_occ_given_free;
  const double free_free = counts[1][1] + w * (1.0 - prior.p_occ_given_free);
  const double from_occ = occ_free + occ_occ;
  const double from_free = free_occ + free_free;
  const auto bounded = [&](double p) { return std::clamp(p, config.p_min, config.p_max); };
  if (config.symmetric) {
    const double all = from_occ + from_free;
    if (!(all > 0.0)) return previous;
    const double p_change = bounded((occ_free + free_occ) / all);
    return TransitionParams{p_change, p_change};
  }
  TransitionParams params = previous;
  if (from_free > 0.0) params.p_occ_given_free = bounded(free_occ / from_free);
  if (from_occ > 0.0) params.p_free_given_occ = bounded(occ_free / from_occ);
  return params;
}

namespace {

// The logit of p, finite even for p = 0 or 1 (bounds of 0 or 1 allowed by the config).
double finiteLogit(double p) {
  const double q = std::clamp(p, 1e-13, 1.0 - 1e-13);
  return std::log(q / (1.0 - q));
}

double sigmoid(double x) { return x >= 0.0 ? 1.0 / (1.0 + std::exp(-x)) : std::exp(x) / (1.0 + std::exp(x)); }

constexpr int kMaxNewtonIterations = 100;  // per M-step and map; Newton needs 2 to 10

// EM whose M-step is the joint MRF problem of mrf.h, one for p(occ -> occ) and one for
// p(free -> free). The E-step is the plain one, cell by cell in parallel.
OfflineEmResult runOfflineEmMrf(const ObservationSequences& sequences, const ObservationModel& sensor,
                                const OfflineEmConfig& config, const OfflineEmProgress& progress) {
  const std::size_t cells = sequences.cellCount();
  OfflineEmResult result;
  result.params.assign(cells, config.initial_params);
  result.final_p_occ.assign(cells, std::numeric_limits<double>::quiet_NaN());
  result.final_step.assign(cells, 0);
  result.iterations.assign(cells, 0);
  if (cells == 0) return result;

  std::vector<CellXY> coordinates(cells);
  for (std::size_t c = 0; c < cells; ++c) coordinates[c] = sequences.cell(c);
  MrfEm mrf(std::move(coordinates), config);
  OfflineEStep e;
  const auto e_step = [&]() {
    e = offlineEStep(sequences, sensor, mrf.params(), config.initial_p_occ, config.threads);
    result.final_p_occ = e.final_p_occ;
    return mrf.objective(e.log_likelihood);
  };

  double objective = e_step();
  result.objective.push_back(objective);
  const auto report = [&](std::size_t iterations_done) {
    if (!progress) return true;
    const auto total = static_cast<std::size_t>(config.max_iterations);
    return progress(total == 0 ? cells : cells * iterations_done / total, cells);
  };
  std::size_t iteration = 0;
  bool converged = false;
  while (iteration < static_cast<std::size_t>(config.max_iterations)) {
    result.mrf_newton_iterations.push_back(mrf.mStep(e.counts));
    const double next_objective = e_step();
    const double gain = next_objective - objective;
    objective = next_objective;
    result.objective.push_back(objective);
    ++iteration;
    if (!report(iteration)) {
      result.cancelled = true;
      break;
    }
    if (mrf.converged(gain)) {
      converged = true;
      break;
    }
  }
  result.params = mrf.params();
  for (std::size_t c = 0; c < cells; ++c) {
    result.final_step[c] = (sequences.end(c) - 1)->step;
    result.iterations[c] = static_cast<std::uint16_t>(iteration);
  }
  if (converged) result.cells_converged = cells;
  return result;
}

}  // namespace

OfflineEStep offlineEStep(const ObservationSequences& sequences, const ObservationModel& sensor,
                          const std::vector<TransitionParams>& params, double initial_p_occ, unsigned threads) {
  const std::size_t cells = sequences.cellCount();
  if (params.size() != cells) {
    throw std::invalid_argument("offlineEStep: " + std::to_string(params.size()) + " parameters for " +
                                std::to_string(cells) + " cells");
  }
  OfflineEStep e;
  e.counts.resize(cells);
  e.log_likelihood.resize(cells);
  e.final_p_occ.resize(cells);
  if (cells == 0) return e;
  const std::size_t chunk_cells = chunkCells(cells);
  const std::size_t chunks = (cells + chunk_cells - 1) / chunk_cells;
  const unsigned hardware = std::max(1U, std::thread::hardware_concurrency());
  const std::size_t thread_count = std::min<std::size_t>(threads == 0 ? hardware : threads, chunks);
  std::atomic<std::size_t> next_chunk{0};
  std::mutex failure_mutex;
  std::exception_ptr failure;
  const auto worker = [&]() {
    try {
      Scratch scratch(sensor);
      scratch.emissions = false;  // the MRF does not learn the sensor model
      for (std::size_t chunk = next_chunk++; chunk < chunks; chunk = next_chunk++) {
        const std::size_t last = std::min(cells, (chunk + 1) * chunk_cells);
        for (std::size_t c = chunk * chunk_cells; c < last; ++c) {
          prepare(sequences.begin(c), sequences.end(c), scratch);
          const ForwardBackwardResult pass = forwardBackwardPrepared(scratch, params[c], initial_p_occ);
          e.counts[c] = pass.counts;
          e.log_likelihood[c] = pass.log_likelihood;
          e.final_p_occ[c] = pass.final_p_occ;
        }
      }
    } catch (...) {
      const std::lock_guard<std::mutex> lock(failure_mutex);
      if (!failure) failure = std::current_exception();
      next_chunk = chunks;
    }
  };
  runOnThreads(thread_count, worker);
  if (failure) std::rethrow_exception(failure);
  return e;
}

MrfEm::MrfEm(std::vector<CellXY> cells, const OfflineEmConfig& config)
    : config_(config), graph_(eightNeighbours(cells)), cells_(cells.size()) {
  config.validate();
  if (!(config.mrf_temperature > 0.0)) throw std::invalid_argument("MrfEm needs mrf_temperature > 0");
  // a_occ = p(occ -> occ) = 1 - p_free_given_occ, a_free = 1 - p_occ_given_free: the bounds
  // [p_min, p_max] of the change probabilities become [1 - p_max, 1 - p_min] of the a's.
  lo_ = finiteLogit(1.0 - config.p_max);
  hi_ = finiteLogit(1.0 - config.p_min);
  params_.assign(cells_, config.initial_params);
  logit_occ_.assign(cells_, finiteLogit(1.0 - config.initial_params.p_free_given_occ));
  logit_free_.assign(cells_, finiteLogit(1.0 - config.initial_params.p_occ_given_free));
}

void MrfEm::restore(std::vector<TransitionParams> params, std::vector<double> logit_occ,
                    std::vector<double> logit_free) {
  if (params.size() != cells_ || logit_occ.size() != cells_ || logit_free.size() != cells_) {
    throw std::invalid_argument("MrfEm::restore: not one value per cell");
  }
  params_ = std::move(params);
  logit_occ_ = std::move(logit_occ);
  logit_free_ = std::move(logit_free);
}

double MrfEm::objective(const std::vector<double>& log_likelihood) const {
  if (log_likelihood.size() != cells_) throw std::invalid_argument("MrfEm::objective: not one value per cell");
  const double lambda = 1.0 / config_.mrf_temperature;
  // Summed in cell order: the same objective for any number of threads.
  double objective = 0.0;
  for (std::size_t c = 0; c < cells_; ++c) objective += log_likelihood[c] + logPrior(params_[c], config_);
  return objective + mrfPrior(graph_, lambda, logit_occ_) + mrfPrior(graph_, lambda, logit_free_);
}

bool MrfEm::converged(double gain) const {
  return config_.tolerance > 0.0 && gain < config_.tolerance * static_cast<double>(cells_);
}

std::array<int, 2> MrfEm::mStep(const std::vector<TransitionCounts>& counts) {
  if (counts.size() != cells_) throw std::invalid_argument("MrfEm::mStep: not one count per cell");
  const double w = config_.prior_weight;
  // An M-step need not be exact, only gain (generalised EM): each map's Newton takes a step
  // predicted to add less than 1 % of the gain at which EM itself stops, and stops there.
  // Tolerance 0 solves every M-step exactly.
  const double newton_gain_tolerance =
      std::min(0.01 * config_.tolerance * static_cast<double>(cells_), std::numeric_limits<double>::max());
  MrfMapProblem occ;
  MrfMapProblem free;
  for (MrfMapProblem* problem : {&occ, &free}) {
    problem->graph = &graph_;
    problem->inverse_temperature = 1.0 / config_.mrf_temperature;
    problem->lo = lo_;
    problem->hi = hi_;
    problem->stay.resize(cells_);
    problem->leave.resize(cells_);
  }
  for (std::size_t c = 0; c < cells_; ++c) {
    // Expected counts plus the MAP prior's pseudo-counts, as offlineMStep adds them.
    occ.stay[c] = counts[c][0][0] + w * (1.0 - config_.prior.p_free_given_occ);
    occ.leave[c] = counts[c][0][1] + w * config_.prior.p_free_given_occ;
    free.stay[c] = counts[c][1][1] + w * (1.0 - config_.prior.p_occ_given_free);
    free.leave[c] = counts[c][1][0] + w * config_.prior.p_occ_given_free;
  }
  std::array<int, 2> newton{0, 0};
  // The two maps are independent problems: one per core.
  const unsigned hardware = std::max(1U, std::thread::hardware_concurrency());
  std::optional<std::thread> other;
  std::exception_ptr failure;
  if ((config_.threads == 0 ? hardware : config_.threads) > 1) {
    try {
      other.emplace([&]() {
        try {
          newton[1] = maximizeMrfMap(free, logit_free_, kMaxNewtonIterations, newton_gain_tolerance);
        } catch (...) {
          failure = std::current_exception();
        }
      });
    } catch (const std::system_error&) {
      other.reset();  // no second thread: both maps on this one
    }
  }
  if (other) {
    try {
      newton[0] = maximizeMrfMap(occ, logit_occ_, kMaxNewtonIterations, newton_gain_tolerance);
    } catch (...) {
      other->join();
      throw;
    }
    other->join();
    if (failure) std::rethrow_exception(failure);
  } else {
    newton[0] = maximizeMrfMap(occ, logit_occ_, kMaxNewtonIterations, newton_gain_tolerance);
    newton[1] = maximizeMrfMap(free, logit_free_, kMaxNewtonIterations, newton_gain_tolerance);
  }
  // The logit bounds are the probability bounds; the clamp only removes rounding.
  for (std::size_t c = 0; c < cells_; ++c) {
    params_[c] = TransitionParams{std::clamp(sigmoid(-logit_free_[c]), config_.p_min, config_.p_max),
                                  std::clamp(sigmoid(-logit_occ_[c]), config_.p_min, config_.p_max)};
  }
  return newton;
}

namespace {

// Per-cell EM with a fixed sensor model, each cell from (*start)[cell] (or the config's
// initial_params); with learn_sensor_model, result.sensor_*_sum get the sensor model's
// E-step at the cells' final transitions, summed exactly (the same for any number of
// threads and any split of the cells).
OfflineEmResult runPerCellEm(const ObservationSequences& sequences, const ObservationModel& sensor,
                             const OfflineEmConfig& config, const std::vector<TransitionParams>* start,
                             const OfflineEmProgress& progress) {
  const std::size_t cells = sequences.cellCount();
  const auto iterations_max = static_cast<std::size_t>(config.max_iterations);
  OfflineEmResult result;
  result.params.assign(cells, config.initial_params);
  result.final_p_occ.assign(cells, std::numeric_limits<double>::quiet_NaN());
  result.final_step.assign(cells, 0);
  result.iterations.assign(cells, 0);
  if (cells == 0) return result;

  const std::size_t chunk_cells = chunkCells(cells);
  const std::size_t chunks = (cells + chunk_cells - 1) / chunk_cells;
  std::vector<std::vector<double>> chunk_objective(chunks);
  std::vector<std::size_t> chunk_converged(chunks, 0);
  struct EmissionSums {
    std::array<FixedPointSum, 2> trials;
    std::array<FixedPointSum, 2> hits;
  };
  std::vector<EmissionSums> chunk_emission(chunks);
  std::atomic<std::size_t> next_chunk{0};
  std::atomic<bool> cancelled{false};
  std::mutex progress_mutex;
  std::size_t cells_done = 0;
  std::exception_ptr failure;

  const auto run_chunk = [&](std::size_t chunk, Scratch& scratch) {
    // Sum over the chunk's cells of their objective at iteration k; a cell that stopped
    // contributes its last value, so extending the sum repeats its last entry.
    std::vector<double>& objective_sum = chunk_objective[chunk];
    objective_sum.assign(1, 0.0);
    const std::size_t first = chunk * chunk_cells;
    const std::size_t last = std::min(cells, first + chunk_cells);
    for (std::size_t cell = first; cell < last; ++cell) {
      const StepObservation* begin = sequences.begin(cell);
      const StepObservation* end = sequences.end(cell);
      prepare(begin, end, scratch);
      TransitionParams params = start != nullptr ? (*start)[cell] : config.initial_params;
      ForwardBackwardResult pass = forwardBackwardPrepared(scratch, params, config.initial_p_occ);
      double objective = pass.log_likelihood + logPrior(params, config);
      scratch.objective.assign(1, objective);
      std::size_t iteration = 0;
      bool converged = false;
      while (iteration < iterations_max) {
        params = offlineMStep(pass.counts, config, params);
        pass = forwardBackwardPrepared(scratch, params, config.initial_p_occ);
        const double next_objective = pass.log_likelihood + logPrior(params, config);
        const double gain = next_objective - objective;
        objective = next_objective;
        scratch.objective.push_back(objective);
        ++iteration;
        // tolerance 0 runs max_iterations (rounding can make a converged gain negative).
        if (config.tolerance > 0.0 && gain < config.tolerance) {
          converged = true;
          break;
        }
      }
      result.params[cell] = params;
      result.final_p_occ[cell] = pass.final_p_occ;
      result.final_step[cell] = (end - 1)->step;
      result.iterations[cell] = static_cast<std::uint16_t>(iteration);
      for (int state = 0; state < 2; ++state) {
        chunk_emission[chunk].trials[state].add(pass.expected_trials[state]);
        chunk_emission[chunk].hits[state].add(pass.expected_hits[state]);
      }
      if (converged) ++chunk_converged[chunk];
      if (scratch.objective.size() > objective_sum.size()) {
        objective_sum.resize(scratch.objective.size(), objective_sum.back());
      }
      for (std::size_t k = 0; k < objective_sum.size(); ++k) {
        objective_sum[k] += scratch.objective[std::min(k, scratch.objective.size() - 1)];
      }
    }
    if (progress) {
      const std::lock_guard<std::mutex> lock(progress_mutex);
      cells_done += last - first;
      if (!progress(cells_done, cells)) cancelled = true;
    }
  };

  const auto worker = [&]() {
    try {
      Scratch scratch(sensor);
      scratch.emissions = config.learn_sensor_model;
      for (std::size_t chunk = next_chunk++; chunk < chunks && !cancelled; chunk = next_chunk++) {
        run_chunk(chunk, scratch);
      }
    } catch (...) {
      const std::lock_guard<std::mutex> lock(progress_mutex);
      if (!failure) failure = std::current_exception();
      cancelled = true;
    }
  };

  const unsigned hardware = std::max(1U, std::thread::hardware_concurrency());
  const std::size_t thread_count = std::min<std::size_t>(config.threads == 0 ? hardware : config.threads, chunks);
  runOnThreads(thread_count, worker);
  if (failure) std::rethrow_exception(failure);

  result.cancelled = cancelled;
  std::size_t entries = 0;
  for (const std::vector<double>& sum : chunk_objective) entries = std::max(entries, sum.size());
  result.objective.assign(entries, 0.0);
  for (std::size_t chunk = 0; chunk < chunks; ++chunk) {
    result.cells_converged += chunk_converged[chunk];
    const std::vector<double>& sum = chunk_objective[chunk];
    if (sum.empty()) continue;  // not run (cancelled)
    for (std::size_t k = 0; k < entries; ++k) result.objective[k] += sum[std::min(k, sum.size() - 1)];
    for (int state = 0; state < 2; ++state) {
      result.sensor_trials_sum[state].add(chunk_emission[chunk].trials[state]);
      result.sensor_hits_sum[state].add(chunk_emission[chunk].hits[state]);
    }
  }
  for (int state = 0; state < 2; ++state) {
    result.sensor_trials[state] = result.sensor_trials_sum[state].value();
    result.sensor_hits[state] = result.sensor_hits_sum[state].value();
  }
  return result;
}

}  // namespace

void FixedPointSum::add(double value) {
  if (!(value >= 0.0) || !(value < 0x1p90)) {
    throw std::invalid_argument("FixedPointSum: cannot add " + std::to_string(value));
  }
  units_ += static_cast<Units>(std::nearbyint(std::ldexp(value, 32)));
}

double FixedPointSum::value() const { return std::ldexp(static_cast<double>(units_), -32); }

FixedPointSum FixedPointSum::fromHalves(std::uint64_t high, std::uint64_t low) {
  FixedPointSum sum;
  sum.units_ = (static_cast<Units>(high) << 64) | low;
  return sum;
}

OfflineEmResult runOfflineEmRound(const ObservationSequences& sequences, const ObservationModel& sensor,
                                  const OfflineEmConfig& config, const std::vector<TransitionParams>& start,
                                  const OfflineEmProgress& progress) {
  config.validate();
  if (!config.learn_sensor_model) throw std::invalid_argument("runOfflineEmRound needs learn_sensor_model");
  if (!start.empty() && start.size() != sequences.cellCount()) {
    throw std::invalid_argument("runOfflineEmRound: " + std::to_string(start.size()) + " start values for " +
                                std::to_string(sequences.cellCount()) + " cells");
  }
  OfflineEmResult result = runPerCellEm(sequences, sensor, config, start.empty() ? nullptr : &start, progress);
  result.p_hit_given_occ = sensor.pHitGivenOcc();
  result.p_hit_given_free = sensor.pHitGivenFree();
  return result;
}

std::optional<ObservationModel> nextSensorModel(const std::array<FixedPointSum, 2>& trials,
                                                const std::array<FixedPointSum, 2>& hits,
                                                const ObservationModel& used, const OfflineEmConfig& config) {
  const double lo = config.sensor_model_p_min;
  const auto rate = [&](int state, double fallback) {
    const double n = trials[state].value();
    return n > 0.0 ? std::clamp(hits[state].value() / n, lo, 1.0 - lo) : fallback;
  };
  const double occ = rate(0, used.pHitGivenOcc());
  const double free = rate(1, used.pHitGivenFree());
  if (occ < free + 0.05) return std::nullopt;  // a hit must stay evidence for "occupied"
  const double moved = std::max(std::abs(occ - used.pHitGivenOcc()), std::abs(free - used.pHitGivenFree()));
  if (moved <= 1e-4) return std::nullopt;
  return ObservationModel(occ, free, used.mixedStepProbability());
}

OfflineEmResult runOfflineEm(const ObservationSequences& sequences, const ObservationModel& sensor,
                             const OfflineEmConfig& config, const OfflineEmProgress& progress) {
  config.validate();
  if (config.mrf_temperature > 0.0) {
    OfflineEmResult result = runOfflineEmMrf(sequences, sensor, config, progress);
    result.p_hit_given_occ = sensor.pHitGivenOcc();
    result.p_hit_given_free = sensor.pHitGivenFree();
    return result;
  }
  if (!config.learn_sensor_model) {
    OfflineEmResult result = runPerCellEm(sequences, sensor, config, nullptr, progress);
    result.p_hit_given_occ = sensor.pHitGivenOcc();
    result.p_hit_given_free = sensor.pHitGivenFree();
    return result;
  }
  // Rounds of per-cell EM under a fixed sensor model, each followed by the emission M-step;
  // the cells' next round starts from their transitions.
  ObservationModel current = sensor;
  const auto rounds = static_cast<std::size_t>(config.sensor_model_rounds);
  const std::size_t cells = sequences.cellCount();
  OfflineEmResult result;
  for (std::size_t round = 0; round < rounds; ++round) {
    const OfflineEmProgress round_progress = [&](std::size_t done, std::size_t total) {
      return !progress || progress(round * total + done, rounds * total);
    };
    const std::vector<TransitionParams> start = round == 0 ? std::vector<TransitionParams>{} : result.params;
    const int rounds_before = result.sensor_model_rounds;
    result = runOfflineEmRound(sequences, current, config, start, round_progress);
    result.sensor_model_rounds = round == 0 ? 1 : rounds_before + 1;
    if (result.cancelled || cells == 0) break;
    const std::optional<ObservationModel> next =
        nextSensorModel(result.sensor_trials_sum, result.sensor_hits_sum, current, config);
    if (!next) break;
    if (round + 1 < rounds) current = *next;
  }
  return result;
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
