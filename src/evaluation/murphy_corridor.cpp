#include "dynamic_occupancy_grid/evaluation/murphy_corridor.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

#include "dynamic_occupancy_grid/core/common/parallel.h"
#include "dynamic_occupancy_grid/core/pose/resampling.h"

namespace dynamic_occupancy_grid {
namespace evaluation {
namespace {

std::uint8_t labelOf(std::uint32_t map, int cell) { return static_cast<std::uint8_t>((map >> cell) & 1U); }

int stepOf(Move move) { return move == Move::kRight ? 1 : -1; }

// p(L_t) from p(L_{t-1}) and A_t: sum_i Pr(L_t = j | L_{t-1} = i, a) p(i) (Section 2).
std::vector<double> propagate(const CorridorModel& model, const std::vector<double>& from, Move move) {
  const int n = model.cells;
  std::vector<double> to(static_cast<std::size_t>(n), 0.0);
  for (int i = 0; i < n; ++i) {
    const int target = i + stepOf(move);
    if (target < 0 || target >= n) {
      to[i] += from[i];  // at the end it moves towards: stays
      continue;
    }
    to[target] += model.p_action * from[i];
    to[i] += (1.0 - model.p_action) * from[i];
  }
  return to;
}

// The transpose: g(i) = sum_j Pr(L_t = j | L_{t-1} = i, a) h(j), the backward pass's step.
void propagateBack(const CorridorModel& model, const double* h, Move move, double* g) {
  const int n = model.cells;
  for (int i = 0; i < n; ++i) {
    const int target = i + stepOf(move);
    g[i] = target < 0 || target >= n ? h[i] : model.p_action * h[target] + (1.0 - model.p_action) * h[i];
  }
}

// Pr(Z = z | L = i; B) of the EM's observation matrix, b_one[i] = B(i, 1).
double emission(const std::vector<double>& b_one, int cell, std::uint8_t z) {
  return z == 1 ? b_one[cell] : 1.0 - b_one[cell];
}

double normalize(std::vector<double>& p) {
  double sum = 0.0;
  for (const double v : p) sum += v;
  if (!(sum > 0.0)) throw std::logic_error("murphy_corridor: a distribution lost all its mass");
  for (double& v : p) v /= sum;
  return sum;
}

// Forward–backward over the positions of steps [first, last] given the EM's observation
// matrix, from `initial` = p(L_first) before z_first is seen.
struct PositionSmoothing {
  std::vector<std::vector<double>> smoothed;  ///< [tau - first][cell]
  double log_likelihood = 0.0;                ///< log p(z_first..z_last | initial; B)
};
PositionSmoothing smoothPositions(const CorridorModel& model, const CorridorEpisode& episode, int first, int last,
                                  const std::vector<double>& initial, const std::vector<double>& b_one) {
  const int n = model.cells;
  const auto length = static_cast<std::size_t>(last - first + 1);
  PositionSmoothing out;
  std::vector<std::vector<double>> alpha(length);
  for (std::size_t k = 0; k < length; ++k) {
    const int t = first + static_cast<int>(k);
    alpha[k] = k == 0 ? initial : propagate(model, alpha[k - 1], episode.actions[t]);
    for (int i = 0; i < n; ++i) alpha[k][i] *= emission(b_one, i, episode.observations[t]);
    out.log_likelihood += std::log(normalize(alpha[k]));
  }
  out.smoothed.resize(length);
  std::vector<double> beta(static_cast<std::size_t>(n), 1.0);
  std::vector<double> h(static_cast<std::size_t>(n));
  for (std::size_t k = length; k-- > 0;) {
    if (k + 1 < length) {
      const int next = first + static_cast<int>(k) + 1;
      for (int i = 0; i < n; ++i) h[i] = emission(b_one, i, episode.observations[next]) * beta[i];
      propagateBack(model, h.data(), episode.actions[next], beta.data());
      normalize(beta);  // any scale will do
    }
    out.smoothed[k] = alpha[k];
    for (int i = 0; i < n; ++i) out.smoothed[k][i] *= beta[i];
    normalize(out.smoothed[k]);
  }
  return out;
}

std::vector<double> startDistribution(const CorridorModel& model) {
  std::vector<double> start(static_cast<std::size_t>(model.cells), 0.0);
  start[0] = 1.0;  // the paper's delta prior on the left-most cell
  return start;
}

// The constrained M-step: B(i, 1) maximising c_1 log b + c_0 log(1 - b) over
// b in [1 - p_o, p_o] (concave: the clamped fraction of ones); 0.5 without counts.
double mStep(const CorridorModel& model, double zeros, double ones) {
  const double total = zeros + ones;
  if (!(total > 1e-12)) return 0.5;
  return std::clamp(ones / total, 1.0 - model.p_observation, model.p_observation);
}

// The map value m = Pr(M(i) = 1) of B(i, 1) = p_o m + (1 - p_o)(1 - m).
double mapOfEmission(const CorridorModel& model, double b_one) {
  return (b_one - (1.0 - model.p_observation)) / (2.0 * model.p_observation - 1.0);
}

// One particle set of the RBPF, flat: particle j's cell i at [j * cells + i].
struct Particles {
  std::vector<int> position;
  std::vector<double> p_one;          ///< p(M(i) = 1) at step `updated`
  std::vector<std::int64_t> updated;  ///< the step p_one refers to
};

// z's likelihood given the cell's p(M = 1): sum_m Pr(z | m) p(m).
double predictiveLikelihood(const CorridorModel& model, double p_one, std::uint8_t z) {
  const double p_o = model.p_observation;
  return z == 1 ? p_o * p_one + (1.0 - p_o) * (1.0 - p_one) : (1.0 - p_o) * p_one + p_o * (1.0 - p_one);
}

}  // namespace

void CorridorModel::validate() const {
  if (cells < 2 || cells > 30) throw std::invalid_argument("CorridorModel: cells must be in [2, 30]");
  if (!(p_action >= 0.0 && p_action <= 1.0)) throw std::invalid_argument("CorridorModel: p_action must be in [0, 1]");
  if (!(p_observation > 0.5 && p_observation < 1.0)) {
    throw std::invalid_argument("CorridorModel: p_observation must be in (0.5, 1)");
  }
  if (!(p_change >= 0.0 && p_change <= 0.5)) throw std::invalid_argument("CorridorModel: p_change must be in [0, 0.5]");
}

CorridorModel murphyModel() { return CorridorModel{}; }

void CorridorEpisode::validate(const CorridorModel& model) const {
  const std::size_t steps = observations.size();
  if (steps == 0) throw std::invalid_argument("CorridorEpisode: no steps");
  if (actions.size() != steps || positions.size() != steps || maps.size() != steps) {
    throw std::invalid_argument("CorridorEpisode: actions, observations, positions and maps need one entry per step");
  }
  for (std::size_t t = 0; t < steps; ++t) {
    if (observations[t] > 1) throw std::invalid_argument("CorridorEpisode: an observation is not 0 or 1");
    if (positions[t] < 0 || positions[t] >= model.cells) {
      throw std::invalid_argument("CorridorEpisode: a position is outside the corridor");
    }
    if (model.cells < 32 && (maps[t] >> model.cells) != 0) {
      throw std::invalid_argument("CorridorEpisode: a map has labels beyond the corridor");
    }
  }
}

std::vector<Move> murphyActions() {
  std::vector<Move> actions(16, Move::kLeft);
  for (int t = 0; t <= 8; ++t) actions[t] = Move::kRight;  // index 0 unused; t = 2..9 right
  return actions;
}

CorridorEpisode murphyEpisode() {
  CorridorEpisode episode;
  episode.actions = murphyActions();
  // The paper's table, 1-based cells: 1 2 3 4 4 5 6 7 8 7 6 5 4 3 2 1 (the slip: L_4 = L_5).
  episode.positions = {0, 1, 2, 3, 3, 4, 5, 6, 7, 6, 5, 4, 3, 2, 1, 0};
  episode.observations = {0, 1, 0, 1, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0, 1, 0};
  // 01010101 from cell 1: the odd (1-based) cells are 0, the even ones 1; bit i = cell i + 1.
  episode.maps.assign(episode.observations.size(), 0xAAU);
  return episode;
}

CorridorEpisode simulateCorridor(const CorridorModel& model, const std::vector<Move>& actions, std::uint64_t seed) {
  model.validate();
  if (actions.empty()) throw std::invalid_argument("simulateCorridor: no actions");
  Rng rng(seed);
  CorridorEpisode episode;
  episode.actions = actions;
  std::uint32_t map = 0;
  for (int i = 0; i < model.cells; ++i) {
    if (rng.bernoulli(0.5)) map |= 1U << i;  // the uniform prior over maps
  }
  int position = 0;
  for (std::size_t t = 0; t < actions.size(); ++t) {
    if (t > 0) {
      const int target = position + stepOf(actions[t]);
      if (target >= 0 && target < model.cells && rng.bernoulli(model.p_action)) position = target;
      if (model.p_change > 0.0) {
        for (int i = 0; i < model.cells; ++i) {
          if (rng.bernoulli(model.p_change)) map ^= 1U << i;
        }
      }
    }
    std::uint8_t z = labelOf(map, position);
    if (!rng.bernoulli(model.p_observation)) z = static_cast<std::uint8_t>(1 - z);
    episode.positions.push_back(position);
    episode.maps.push_back(map);
    episode.observations.push_back(z);
  }
  return episode;
}

double positionTransition(const CorridorModel& model, int from, int to, Move move) {
  const int target = from + stepOf(move);
  if (target < 0 || target >= model.cells) return to == from ? 1.0 : 0.0;
  if (to == target) return model.p_action;
  if (to == from) return 1.0 - model.p_action;
  return 0.0;
}

double observationLikelihood(const CorridorModel& model, std::uint8_t z, std::uint8_t label) {
  return z == label ? model.p_observation : 1.0 - model.p_observation;
}

ExactCorridorPosterior exactCorridorPosterior(const CorridorModel& model, const CorridorEpisode& episode) {
  model.validate();
  episode.validate(model);
  if (model.cells > kMaxExactCorridorCells) {
    throw std::invalid_argument("exactCorridorPosterior: at most " + std::to_string(kMaxExactCorridorCells) +
                                " cells can be enumerated");
  }
  const int n = model.cells;
  const std::size_t maps = std::size_t{1} << n;
  const std::size_t states = maps * static_cast<std::size_t>(n);
  const std::size_t steps = episode.steps();
  const double p_c = model.p_change;

  // Per-cell flips of the map, one cell at a time (the map's transition is their product).
  const auto flipMaps = [&](std::vector<double>& b) {
    if (p_c == 0.0) return;
    for (int i = 0; i < n; ++i) {
      const std::size_t bit = std::size_t{1} << i;
      for (std::size_t m = 0; m < maps; ++m) {
        if ((m & bit) != 0) continue;
        double* keep = &b[m * n];
        double* flip = &b[(m | bit) * n];
        for (int l = 0; l < n; ++l) {
          const double x = keep[l];
          const double y = flip[l];
          keep[l] = (1.0 - p_c) * x + p_c * y;
          flip[l] = p_c * x + (1.0 - p_c) * y;
        }
      }
    }
  };
  const auto observe = [&](std::vector<double>& b, std::uint8_t z) {
    for (std::size_t m = 0; m < maps; ++m) {
      for (int l = 0; l < n; ++l) b[m * n + l] *= observationLikelihood(model, z, labelOf(static_cast<std::uint32_t>(m), l));
    }
  };
  const auto marginals = [&](const std::vector<double>& b, std::vector<double>& position, std::vector<double>& map_one,
                             std::vector<double>* map_probability) {
    position.assign(static_cast<std::size_t>(n), 0.0);
    map_one.assign(static_cast<std::size_t>(n), 0.0);
    if (map_probability != nullptr) map_probability->assign(maps, 0.0);
    for (std::size_t m = 0; m < maps; ++m) {
      double p_map = 0.0;
      for (int l = 0; l < n; ++l) {
        position[l] += b[m * n + l];
        p_map += b[m * n + l];
      }
      for (int i = 0; i < n; ++i) {
        if (labelOf(static_cast<std::uint32_t>(m), i) == 1) map_one[i] += p_map;
      }
      if (map_probability != nullptr) (*map_probability)[m] = p_map;
    }
  };

  ExactCorridorPosterior out;
  out.filtered.position.resize(steps);
  out.filtered.map_one.resize(steps);
  out.smoothed.position.resize(steps);
  out.smoothed.map_one.resize(steps);
  out.maps.resize(steps);
  // Forward: alpha_t(m, l) = p(M_t = m, L_t = l | y_{1:t}).
  std::vector<std::vector<double>> alpha(steps);
  std::vector<double> row(static_cast<std::size_t>(n));
  for (std::size_t t = 0; t < steps; ++t) {
    std::vector<double>& b = alpha[t];
    if (t == 0) {
      b.assign(states, 0.0);
      for (std::size_t m = 0; m < maps; ++m) b[m * n] = 1.0 / static_cast<double>(maps);  // L_1 = cell 1
    } else {
      b.assign(states, 0.0);
      const std::vector<double>& previous = alpha[t - 1];
      for (std::size_t m = 0; m < maps; ++m) {
        row.assign(previous.begin() + static_cast<std::ptrdiff_t>(m * n),
                   previous.begin() + static_cast<std::ptrdiff_t>((m + 1) * n));
        const std::vector<double> moved = propagate(model, row, episode.actions[t]);
        std::copy(moved.begin(), moved.end(), b.begin() + static_cast<std::ptrdiff_t>(m * n));
      }
      flipMaps(b);
    }
    observe(b, episode.observations[t]);
    out.log_likelihood += std::log(normalize(b));
    marginals(b, out.filtered.position[t], out.filtered.map_one[t], &out.maps[t]);
  }
  // Backward: beta_t(m, l) proportional to p(y_{t+1:T} | M_t = m, L_t = l).
  std::vector<double> beta(states, 1.0);
  std::vector<double> h(states);
  std::vector<double> gamma(states);
  for (std::size_t t = steps; t-- > 0;) {
    if (t + 1 < steps) {
      h = beta;
      observe(h, episode.observations[t + 1]);
      for (std::size_t m = 0; m < maps; ++m) propagateBack(model, &h[m * n], episode.actions[t + 1], &beta[m * n]);
      flipMaps(beta);  // the flip matrix is symmetric: its transpose is itself
      normalize(beta);
    }
    for (std::size_t s = 0; s < states; ++s) gamma[s] = alpha[t][s] * beta[s];
    normalize(gamma);
    marginals(gamma, out.smoothed.position[t], out.smoothed.map_one[t], nullptr);
  }
  return out;
}

CorridorPosterior deadReckoning(const CorridorModel& model, const CorridorEpisode& episode) {
  model.validate();
  episode.validate(model);
  CorridorPosterior out;
  out.position.push_back(startDistribution(model));
  for (std::size_t t = 1; t < episode.steps(); ++t) {
    out.position.push_back(propagate(model, out.position.back(), episode.actions[t]));
  }
  return out;
}

void CorridorOnlineEmConfig::validate() const {
  if (!(decay > 0.0 && decay < 1.0)) throw std::invalid_argument("CorridorOnlineEmConfig: decay must be in (0, 1)");
}

CorridorPosterior corridorOnlineEm(const CorridorModel& model, const CorridorEpisode& episode,
                                   const CorridorOnlineEmConfig& config) {
  model.validate();
  episode.validate(model);
  config.validate();
  const int n = model.cells;
  const int steps = static_cast<int>(episode.steps());
  std::vector<double> b_one(static_cast<std::size_t>(n), 0.5);  // no map yet: B uninformative
  std::vector<std::array<double, 2>> statistics(static_cast<std::size_t>(n), {0.0, 0.0});
  std::vector<double> before_window;  // smoothed L_{first - 1 | t - 1}, the window's prior
  const auto windowStart = [&](int t) { return config.window < 0 ? 0 : std::max(0, t - config.window); };
  CorridorPosterior out;
  for (int t = 0; t < steps; ++t) {
    // E-step: forward–backward over the window with the map of step t - 1.
    const int first = windowStart(t);
    const std::vector<double> initial =
        first == 0 ? startDistribution(model) : propagate(model, before_window, episode.actions[first]);
    const PositionSmoothing smoothing = smoothPositions(model, episode, first, t, initial, b_one);
    out.position.push_back(smoothing.smoothed.back());
    // theta_t(i, k) = sum over the window's steps with z = k of L_{tau | t}(i);
    // S_t = theta_t + d S_{t-1}; the M-step normalises each row of S_t.
    for (auto& s : statistics) {
      s[0] *= config.decay;
      s[1] *= config.decay;
    }
    for (int tau = first; tau <= t; ++tau) {
      const std::vector<double>& gamma = smoothing.smoothed[static_cast<std::size_t>(tau - first)];
      for (int i = 0; i < n; ++i) statistics[i][episode.observations[tau]] += gamma[i];
    }
    std::vector<double> map(static_cast<std::size_t>(n));
    for (int i = 0; i < n; ++i) {
      b_one[i] = mStep(model, statistics[i][0], statistics[i][1]);
      map[i] = mapOfEmission(model, b_one[i]);
    }
    out.map_one.push_back(std::move(map));
    const int next_first = windowStart(t + 1);
    if (next_first > 0) before_window = smoothing.smoothed[static_cast<std::size_t>(next_first - 1 - first)];
  }
  return out;
}

void CorridorOfflineEmConfig::validate() const {
  if (max_iterations < 0) throw std::invalid_argument("CorridorOfflineEmConfig: max_iterations must be >= 0");
  if (!(tolerance >= 0.0)) throw std::invalid_argument("CorridorOfflineEmConfig: tolerance must be >= 0");
}

CorridorOfflineEmResult corridorOfflineEm(const CorridorModel& model, const CorridorEpisode& episode,
                                          const CorridorOfflineEmConfig& config, int last) {
  model.validate();
  episode.validate(model);
  config.validate();
  const int steps = static_cast<int>(episode.steps());
  if (last < 0) last = steps - 1;
  if (last >= steps) throw std::invalid_argument("corridorOfflineEm: last is beyond the episode");
  const int n = model.cells;
  std::vector<double> b_one(static_cast<std::size_t>(n), 0.5);
  CorridorOfflineEmResult out;
  PositionSmoothing smoothing;
  for (;;) {
    smoothing = smoothPositions(model, episode, 0, last, startDistribution(model), b_one);
    out.log_likelihood.push_back(smoothing.log_likelihood);
    const std::size_t k = out.log_likelihood.size();
    if (out.iterations >= config.max_iterations ||
        (k >= 2 && out.log_likelihood[k - 1] - out.log_likelihood[k - 2] < config.tolerance)) {
      break;
    }
    std::vector<std::array<double, 2>> counts(static_cast<std::size_t>(n), {0.0, 0.0});
    for (int t = 0; t <= last; ++t) {
      for (int i = 0; i < n; ++i) counts[i][episode.observations[t]] += smoothing.smoothed[t][i];
    }
    for (int i = 0; i < n; ++i) b_one[i] = mStep(model, counts[i][0], counts[i][1]);
    ++out.iterations;
  }
  std::vector<double> map(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) map[i] = mapOfEmission(model, b_one[i]);
  out.smoothed.position = std::move(smoothing.smoothed);
  out.smoothed.map_one.assign(static_cast<std::size_t>(last + 1), map);
  return out;
}

CorridorPosterior corridorOfflineEmPerStep(const CorridorModel& model, const CorridorEpisode& episode,
                                           const CorridorOfflineEmConfig& config) {
  CorridorPosterior out;
  for (int t = 0; t < static_cast<int>(episode.steps()); ++t) {
    CorridorOfflineEmResult prefix = corridorOfflineEm(model, episode, config, t);
    out.position.push_back(std::move(prefix.smoothed.position.back()));
    out.map_one.push_back(std::move(prefix.smoothed.map_one.back()));
  }
  return out;
}

std::vector<std::size_t> residualResample(const std::vector<double>& weights, std::size_t count, Rng& rng) {
  return core::residualResample(weights, count, [&rng] { return rng.uniform(); });
}

void CorridorRbpfConfig::validate() const {
  if (particles < 1) throw std::invalid_argument("CorridorRbpfConfig: particles must be >= 1");
  if (!(resample_below >= 0.0 && resample_below <= 1.0)) {
    throw std::invalid_argument("CorridorRbpfConfig: resample_below must be in [0, 1]");
  }
}

CorridorRbpfResult corridorRbpf(const CorridorModel& model, const CorridorEpisode& episode,
                                const CorridorRbpfConfig& config) {
  model.validate();
  episode.validate(model);
  config.validate();
  const int n = model.cells;
  const auto count = static_cast<std::size_t>(config.particles);
  const core::TransitionParams cell_transitions = model.cellTransitions();
  const core::ObservationModel sensor = model.observationModel();
  // log p(z | 1) / p(z | 0) of z = 1 (a hit) and z = 0 (a miss), the core's sensor model.
  const std::array<double, 2> log_likelihood_ratio{sensor.logLikelihoodRatio(0, 1), sensor.logLikelihoodRatio(1, 0)};
  Rng rng(config.seed);

  Particles particles;
  particles.position.assign(count, 0);  // the delta prior
  particles.p_one.assign(count * n, 0.5);  // the uniform prior per cell
  particles.updated.assign(count * n, 0);
  std::vector<double> weights(count, 1.0 / static_cast<double>(count));
  // Particle j's p(M_t(i) = 1): the cell HMM predicted in closed form from its last update.
  const auto predicted = [&](std::size_t j, int i, std::int64_t t) {
    const std::size_t c = j * n + static_cast<std::size_t>(i);
    return core::predictOccupancy(particles.p_one[c], cell_transitions, t - particles.updated[c]);
  };

  CorridorRbpfResult out;
  for (std::size_t t = 0; t < episode.steps(); ++t) {
    const std::uint8_t z = episode.observations[t];
    const auto step = static_cast<std::int64_t>(t);
    for (std::size_t j = 0; j < count; ++j) {
      int& position = particles.position[j];
      double incremental = 0.0;
      if (t > 0 && config.proposal == CorridorProposal::kOptimal) {
        // Pr(L_t | L_{t-1}, a_t, z_t) over the (at most two) cells L_t can be, and the
        // weight p(z_t | L_{t-1}, particle's map) that does not depend on the draw.
        const int target = position + stepOf(episode.actions[t]);
        std::array<int, 2> cells{position, target};
        std::array<double, 2> mass{};
        for (std::size_t k = 0; k < cells.size(); ++k) {
          const double prior = positionTransition(model, position, cells[k], episode.actions[t]);
          mass[k] = prior > 0.0 ? prior * predictiveLikelihood(model, predicted(j, cells[k], step), z) : 0.0;
        }
        incremental = mass[0] + mass[1];
        position = rng.uniform() * incremental < mass[0] ? cells[0] : cells[1];
      } else {
        if (t > 0) {
          const int target = position + stepOf(episode.actions[t]);
          if (target >= 0 && target < n && rng.bernoulli(model.p_action)) position = target;
        }
        incremental = predictiveLikelihood(model, predicted(j, position, step), z);
      }
      // The particle's map given its trajectory: only the cell it stands on sees z_t.
      const std::size_t c = j * n + static_cast<std::size_t>(position);
      particles.p_one[c] = core::bayesUpdate(predicted(j, position, step), log_likelihood_ratio[z]);
      particles.updated[c] = step;
      weights[j] *= incremental;
    }
    double total = 0.0;
    for (const double w : weights) total += w;
    double sum_squares = 0.0;
    for (double& w : weights) {
      w /= total;
      sum_squares += w * w;
    }
    const double effective = 1.0 / sum_squares;
    out.effective_sample_size.push_back(effective);
    std::vector<double> position(static_cast<std::size_t>(n), 0.0);
    std::vector<double> map_one(static_cast<std::size_t>(n), 0.0);
    for (std::size_t j = 0; j < count; ++j) {
      position[particles.position[j]] += weights[j];
      for (int i = 0; i < n; ++i) map_one[i] += weights[j] * predicted(j, i, step);
    }
    out.filtered.position.push_back(std::move(position));
    out.filtered.map_one.push_back(std::move(map_one));
    const bool resample = effective < config.resample_below * static_cast<double>(count);
    out.resampled.push_back(resample ? 1 : 0);
    if (resample) {
      const std::vector<std::size_t> copies = residualResample(weights, count, rng);
      Particles next;
      next.position.reserve(count);
      next.p_one.reserve(count * n);
      next.updated.reserve(count * n);
      for (std::size_t j = 0; j < count; ++j) {
        for (std::size_t k = 0; k < copies[j]; ++k) {
          next.position.push_back(particles.position[j]);
          next.p_one.insert(next.p_one.end(), particles.p_one.begin() + static_cast<std::ptrdiff_t>(j * n),
                            particles.p_one.begin() + static_cast<std::ptrdiff_t>((j + 1) * n));
          next.updated.insert(next.updated.end(), particles.updated.begin() + static_cast<std::ptrdiff_t>(j * n),
                              particles.updated.begin() + static_cast<std::ptrdiff_t>((j + 1) * n));
        }
      }
      particles = std::move(next);
      weights.assign(count, 1.0 / static_cast<double>(count));
    }
  }
  return out;
}

double totalVariation(const std::vector<double>& p, const std::vector<double>& q) {
  if (p.size() != q.size()) throw std::invalid_argument("totalVariation: distributions of different sizes");
  double sum = 0.0;
  for (std::size_t i = 0; i < p.size(); ++i) sum += std::abs(p[i] - q[i]);
  return 0.5 * sum;
}

std::vector<double> sampleHistogram(const std::vector<double>& p, std::size_t count, Rng& rng) {
  if (p.empty() || count == 0) throw std::invalid_argument("sampleHistogram: no cells or no draws");
  std::vector<double> histogram(p.size(), 0.0);
  for (std::size_t k = 0; k < count; ++k) {
    const double u = rng.uniform();
    double cumulative = 0.0;
    std::size_t pick = p.size() - 1;
    for (std::size_t i = 0; i < p.size(); ++i) {
      cumulative += p[i];
      if (u < cumulative) {
        pick = i;
        break;
      }
    }
    histogram[pick] += 1.0 / static_cast<double>(count);
  }
  return histogram;
}

const char* corridorEstimatorName(CorridorEstimator estimator) {
  switch (estimator) {
    case CorridorEstimator::kExact:
      return "exact";
    case CorridorEstimator::kDeadReckoning:
      return "dead_reckoning";
    case CorridorEstimator::kOnlineEm:
      return "online_em";
    case CorridorEstimator::kOnlineEmNoSmoothing:
      return "online_em_no_smoothing";
    case CorridorEstimator::kOfflineEm:
      return "offline_em";
    case CorridorEstimator::kOfflineEmSmoothed:
      return "offline_em_smoothed";
    case CorridorEstimator::kRbpf:
      return "rbpf";
    case CorridorEstimator::kRbpfOptimal:
      return "rbpf_optimal";
  }
  return "unknown";
}

CorridorErrors scoreCorridor(const CorridorPosterior& estimate, const CorridorPosterior& exact,
                             const CorridorEpisode& episode) {
  const std::size_t steps = episode.steps();
  if (estimate.position.size() != steps || exact.position.size() != steps || exact.map_one.size() != steps ||
      (!estimate.map_one.empty() && estimate.map_one.size() != steps)) {
    throw std::invalid_argument("scoreCorridor: an estimate without one entry per step");
  }
  CorridorErrors errors;
  for (std::size_t t = 0; t < steps; ++t) {
    errors.position_tv.push_back(totalVariation(estimate.position[t], exact.position[t]));
    errors.truth_mass.push_back(estimate.position[t].at(static_cast<std::size_t>(episode.positions[t])));
    if (estimate.map_one.empty()) continue;
    const std::size_t cells = exact.map_one[t].size();
    double to_exact = 0.0;
    double to_truth = 0.0;
    for (std::size_t i = 0; i < cells; ++i) {
      const double p = estimate.map_one[t].at(i);
      to_exact += std::abs(p - exact.map_one[t][i]);
      to_truth += std::abs(p - static_cast<double>(labelOf(episode.maps[t], static_cast<int>(i))));
    }
    errors.map_error.push_back(to_exact / static_cast<double>(cells));
    errors.map_truth_error.push_back(to_truth / static_cast<double>(cells));
  }
  return errors;
}

void MurphyExperimentConfig::validate() const {
  if (repetitions <= 0) throw std::invalid_argument("runMurphyExperiment: repetitions must be positive");
  rbpf.validate();
  online_em.validate();
  offline_em.validate();
  if (!(dynamic_p_change > 0.0 && dynamic_p_change <= 0.5)) {
    throw std::invalid_argument("runMurphyExperiment: dynamic_p_change must be in (0, 0.5]");
  }
  for (const int particles : particle_counts) {
    if (particles < 1) throw std::invalid_argument("runMurphyExperiment: a particle count below 1");
  }
}

namespace {

using EstimateSet = std::array<CorridorPosterior, kAllCorridorEstimators.size()>;
using ErrorSet = std::array<CorridorErrors, kAllCorridorEstimators.size()>;

std::size_t indexOf(CorridorEstimator estimator) {
  return static_cast<std::size_t>(std::find(kAllCorridorEstimators.begin(), kAllCorridorEstimators.end(), estimator) -
                                  kAllCorridorEstimators.begin());
}

EstimateSet estimateAll(const CorridorModel& model, const CorridorEpisode& episode, const ExactCorridorPosterior& exact,
                        const MurphyExperimentConfig& config, std::uint64_t rbpf_seed) {
  EstimateSet estimates;
  estimates[indexOf(CorridorEstimator::kExact)] = exact.filtered;
  estimates[indexOf(CorridorEstimator::kDeadReckoning)] = deadReckoning(model, episode);
  estimates[indexOf(CorridorEstimator::kOnlineEm)] = corridorOnlineEm(model, episode, config.online_em);
  CorridorOnlineEmConfig filtering = config.online_em;
  filtering.window = 0;
  estimates[indexOf(CorridorEstimator::kOnlineEmNoSmoothing)] = corridorOnlineEm(model, episode, filtering);
  estimates[indexOf(CorridorEstimator::kOfflineEm)] = corridorOfflineEmPerStep(model, episode, config.offline_em);
  estimates[indexOf(CorridorEstimator::kOfflineEmSmoothed)] =
      corridorOfflineEm(model, episode, config.offline_em).smoothed;
  CorridorRbpfConfig rbpf = config.rbpf;
  rbpf.seed = rbpf_seed;
  rbpf.proposal = CorridorProposal::kTransition;
  estimates[indexOf(CorridorEstimator::kRbpf)] = corridorRbpf(model, episode, rbpf).filtered;
  rbpf.proposal = CorridorProposal::kOptimal;
  estimates[indexOf(CorridorEstimator::kRbpfOptimal)] = corridorRbpf(model, episode, rbpf).filtered;
  return estimates;
}

ErrorSet scoreAll(const EstimateSet& estimates, const ExactCorridorPosterior& exact, const CorridorEpisode& episode) {
  ErrorSet errors;
  for (std::size_t e = 0; e < kAllCorridorEstimators.size(); ++e) {
    const bool smoothed = kAllCorridorEstimators[e] == CorridorEstimator::kOfflineEmSmoothed;
    errors[e] = scoreCorridor(estimates[e], smoothed ? exact.smoothed : exact.filtered, episode);
  }
  return errors;
}

double mean(const std::vector<double>& values) {
  if (values.empty()) return std::numeric_limits<double>::quiet_NaN();
  double sum = 0.0;
  for (const double v : values) sum += v;
  return sum / static_cast<double>(values.size());
}

// Mean over runs of the mean of steps [from, to) of one series of one estimator.
double meanOver(const MurphyVariant& variant, CorridorEstimator estimator, std::vector<double> CorridorErrors::*series,
                int from, int to) {
  std::vector<double> per_run;
  for (const ErrorSet& run : variant.runs) {
    const std::vector<double>& values = run[indexOf(estimator)].*series;
    if (values.empty()) return std::numeric_limits<double>::quiet_NaN();
    const auto end = to < 0 ? values.size() : std::min(values.size(), static_cast<std::size_t>(to));
    const auto begin = std::min(end, static_cast<std::size_t>(std::max(0, from)));
    per_run.push_back(mean(std::vector<double>(values.begin() + static_cast<std::ptrdiff_t>(begin),
                                               values.begin() + static_cast<std::ptrdiff_t>(end))));
  }
  return mean(per_run);
}

struct Run {
  EstimateSet paper_estimates;
  std::array<ErrorSet, 3> errors;  ///< paper, simulated_static, simulated_dynamic
  std::vector<double> sweep_mean_tv;
  std::vector<double> sweep_max_tv;
  std::vector<double> sweep_map_error;
  std::vector<double> sweep_floor_tv;
};

}  // namespace

double MurphyVariant::meanPositionTv(CorridorEstimator estimator, int from, int to) const {
  return meanOver(*this, estimator, &CorridorErrors::position_tv, from, to);
}
double MurphyVariant::meanTruthMass(CorridorEstimator estimator, int from, int to) const {
  return meanOver(*this, estimator, &CorridorErrors::truth_mass, from, to);
}
double MurphyVariant::meanMapError(CorridorEstimator estimator, int from, int to) const {
  return meanOver(*this, estimator, &CorridorErrors::map_error, from, to);
}
double MurphyVariant::maxPositionTv(CorridorEstimator estimator) const {
  double most = 0.0;
  for (const ErrorSet& run : runs) {
    for (const double tv : run[indexOf(estimator)].position_tv) most = std::max(most, tv);
  }
  return most;
}

MurphyExperimentResult runMurphyExperiment(const MurphyExperimentConfig& config,
                                           const std::function<void(int done)>& progress) {
  config.validate();
  const auto start = std::chrono::steady_clock::now();
  MurphyExperimentResult result;
  const CorridorModel paper_model = murphyModel();
  CorridorModel dynamic_model = paper_model;
  dynamic_model.p_change = config.dynamic_p_change;
  result.paper_episode = murphyEpisode();
  result.paper_exact = exactCorridorPosterior(paper_model, result.paper_episode);

  std::vector<Run> runs(static_cast<std::size_t>(config.repetitions));
  core::runRepetitions(
      runs.size(), config.threads,
      [&](std::size_t r) {
        Run& run = runs[r];
        // Derived as the other experiments derive theirs: nearby (seed, r) give unrelated runs.
        const std::uint64_t run_seed = mixSeed(config.seed * 1000003ULL + static_cast<std::uint64_t>(r));
        run.paper_estimates = estimateAll(paper_model, result.paper_episode, result.paper_exact, config, run_seed);
        run.errors[0] = scoreAll(run.paper_estimates, result.paper_exact, result.paper_episode);
        const std::array<const CorridorModel*, 2> simulated{&paper_model, &dynamic_model};
        for (std::size_t v = 0; v < simulated.size(); ++v) {
          const std::uint64_t episode_seed = mixSeed(run_seed ^ (0x636f72ULL + v));  // "cor": its own stream
          const CorridorEpisode episode = simulateCorridor(*simulated[v], murphyActions(), episode_seed);
          const ExactCorridorPosterior exact = exactCorridorPosterior(*simulated[v], episode);
          run.errors[v + 1] = scoreAll(estimateAll(*simulated[v], episode, exact, config, run_seed), exact, episode);
        }
        for (const int particles : config.particle_counts) {
          CorridorRbpfConfig rbpf = config.rbpf;
          rbpf.particles = particles;
          rbpf.seed = mixSeed(run_seed + static_cast<std::uint64_t>(particles));
          const CorridorErrors errors = scoreCorridor(corridorRbpf(paper_model, result.paper_episode, rbpf).filtered,
                                                      result.paper_exact.filtered, result.paper_episode);
          run.sweep_mean_tv.push_back(mean(errors.position_tv));
          run.sweep_max_tv.push_back(*std::max_element(errors.position_tv.begin(), errors.position_tv.end()));
          run.sweep_map_error.push_back(mean(errors.map_error));
          Rng draws(mixSeed(rbpf.seed ^ 0x666c6f6f72ULL));  // "floor": its own stream
          std::vector<double> floor_tv;
          for (const std::vector<double>& exact : result.paper_exact.filtered.position) {
            floor_tv.push_back(totalVariation(sampleHistogram(exact, static_cast<std::size_t>(particles), draws), exact));
          }
          run.sweep_floor_tv.push_back(mean(floor_tv));
        }
      },
      progress);

  result.paper_estimates = runs.front().paper_estimates;
  const std::array<std::pair<const char*, CorridorModel>, 3> variants{
      {{"paper", paper_model}, {"simulated_static", paper_model}, {"simulated_dynamic", dynamic_model}}};
  for (std::size_t v = 0; v < variants.size(); ++v) {
    MurphyVariant variant;
    variant.name = variants[v].first;
    variant.model = variants[v].second;
    for (const Run& run : runs) variant.runs.push_back(run.errors[v]);
    result.variants.push_back(std::move(variant));
  }
  for (std::size_t k = 0; k < config.particle_counts.size(); ++k) {
    MurphyParticleSweepRow row;
    row.particles = config.particle_counts[k];
    for (const Run& run : runs) {
      row.mean_tv.push_back(run.sweep_mean_tv[k]);
      row.max_tv.push_back(run.sweep_max_tv[k]);
      row.map_error.push_back(run.sweep_map_error[k]);
      row.sampling_floor_tv.push_back(run.sweep_floor_tv[k]);
    }
    result.particle_sweep.push_back(std::move(row));
  }
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
