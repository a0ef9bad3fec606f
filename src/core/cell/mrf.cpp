#include "dynamic_occupancy_grid/core/cell/mrf.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <unordered_map>

namespace dynamic_occupancy_grid {
namespace core {
namespace {

double sigmoid(double x) {
  if (x >= 0.0) return 1.0 / (1.0 + std::exp(-x));
  const double e = std::exp(x);
  return e / (1.0 + e);
}

// log sigma(x) without overflow or cancellation.
double logSigmoid(double x) { return x >= 0.0 ? -std::log1p(std::exp(-x)) : x - std::log1p(std::exp(x)); }

std::uint64_t key(const CellXY& c) {
  return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(c.x)) << 32) | static_cast<std::uint32_t>(c.y);
}

void check(const MrfMapProblem& problem, const std::vector<double>& logits) {
  if (problem.graph == nullptr) throw std::invalid_argument("MRF: no neighbour graph");
  const std::size_t n = problem.graph->offsets.size() - 1;
  if (problem.stay.size() != n || problem.leave.size() != n || logits.size() != n) {
    throw std::invalid_argument("MRF: counts, logits and graph must have one entry per cell");
  }
  if (!(std::isfinite(problem.lo) && std::isfinite(problem.hi) && problem.lo <= problem.hi)) {
    throw std::invalid_argument("MRF: the logit bounds must be finite and ordered");
  }
  if (!(std::isfinite(problem.inverse_temperature) && problem.inverse_temperature >= 0.0)) {
    throw std::invalid_argument("MRF: 1 / temperature must be finite and >= 0");
  }
  for (std::size_t i = 0; i < n; ++i) {
    if (!(problem.stay[i] >= 0.0 && problem.leave[i] >= 0.0 && std::isfinite(problem.stay[i]) &&
          std::isfinite(problem.leave[i]))) {
      throw std::invalid_argument("MRF: expected counts must be finite and >= 0");
    }
  }
}

// y = (diag(h) + 2 lambda L) x on the free variables (x and y zero elsewhere).
void applySystem(const CellNeighbours& graph, const std::vector<double>& h, double two_lambda,
                 const std::vector<char>& free, const std::vector<double>& x, std::vector<double>& y) {
  const std::size_t n = h.size();
  for (std::size_t i = 0; i < n; ++i) {
    if (!free[i]) {
      y[i] = 0.0;
      continue;
    }
    double laplacian = 0.0;
    for (std::uint32_t k = graph.offsets[i]; k < graph.offsets[i + 1]; ++k) {
      const std::uint32_t j = graph.indices[k];
      // A fixed neighbour (at a bound) does not move: its x is 0.
      laplacian += x[i] - (free[j] ? x[j] : 0.0);
    }
    y[i] = h[i] * x[i] + two_lambda * laplacian;
  }
}

double dot(const std::vector<double>& a, const std::vector<double>& b) {
  double sum = 0.0;
  for (std::size_t i = 0; i < a.size(); ++i) sum += a[i] * b[i];
  return sum;
}

}  // namespace

CellNeighbours eightNeighbours(const std::vector<CellXY>& cells) {
  std::unordered_map<std::uint64_t, std::uint32_t> index;
  index.reserve(cells.size() * 2);
  for (std::size_t i = 0; i < cells.size(); ++i) {
    if (!index.emplace(key(cells[i]), static_cast<std::uint32_t>(i)).second) {
      throw std::invalid_argument("eightNeighbours: cell (" + std::to_string(cells[i].x) + ", " +
                                  std::to_string(cells[i].y) + ") appears twice");
    }
  }
  CellNeighbours graph;
  graph.offsets.reserve(cells.size() + 1);
  std::vector<std::uint32_t> row;
  for (const CellXY& c : cells) {
    row.clear();
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dx = -1; dx <= 1; ++dx) {
        if (dx == 0 && dy == 0) continue;
        const auto found = index.find(key(CellXY{c.x + dx, c.y + dy}));
        if (found != index.end()) row.push_back(found->second);
      }
    }
    std::sort(row.begin(), row.end());
    graph.indices.insert(graph.indices.end(), row.begin(), row.end());
    graph.offsets.push_back(static_cast<std::uint32_t>(graph.indices.size()));
  }
  return graph;
}

double mrfPrior(const CellNeighbours& graph, double inverse_temperature, const std::vector<double>& logits) {
  double sum = 0.0;
  for (std::size_t i = 0; i + 1 < graph.offsets.size(); ++i) {
    for (std::uint32_t k = graph.offsets[i]; k < graph.offsets[i + 1]; ++k) {
      const std::uint32_t j = graph.indices[k];
      if (j > i) sum += (logits[i] - logits[j]) * (logits[i] - logits[j]);  // each pair once
    }
  }
  return -inverse_temperature * sum;
}

double mrfMapObjective(const MrfMapProblem& problem, const std::vector<double>& logits) {
  check(problem, logits);
  double sum = 0.0;
  for (std::size_t i = 0; i < logits.size(); ++i) {
    // 0 * log(0) is 0: a count of zero contributes nothing, whatever the logit.
    if (problem.stay[i] > 0.0) sum += problem.stay[i] * logSigmoid(logits[i]);
    if (problem.leave[i] > 0.0) sum += problem.leave[i] * logSigmoid(-logits[i]);
  }
  return sum + mrfPrior(*problem.graph, problem.inverse_temperature, logits);
}

std::vector<double> mrfMapGradient(const MrfMapProblem& problem, const std::vector<double>& logits) {
  check(problem, logits);
  const CellNeighbours& graph = *problem.graph;
  std::vector<double> gradient(logits.size());
  for (std::size_t i = 0; i < logits.size(); ++i) {
    // d/dl log sigma(l) = sigma(-l), d/dl log sigma(-l) = -sigma(l).
    double g = problem.stay[i] * sigmoid(-logits[i]) - problem.leave[i] * sigmoid(logits[i]);
    for (std::uint32_t k = graph.offsets[i]; k < graph.offsets[i + 1]; ++k) {
      g -= 2.0 * problem.inverse_temperature * (logits[i] - logits[graph.indices[k]]);
    }
    gradient[i] = g;
  }
  return gradient;
}

double mrfMapObjectiveChange(const MrfMapProblem& problem, const std::vector<double>& from,
                             const std::vector<double>& to) {
  check(problem, from);
  check(problem, to);
  // Term by term: F itself is a sum of many large terms, and its difference between two
  // nearby points would drown in their rounding.
  double change = 0.0;
  for (std::size_t i = 0; i < from.size(); ++i) {
    if (from[i] == to[i]) continue;
    if (problem.stay[i] > 0.0) change += problem.stay[i] * (logSigmoid(to[i]) - logSigmoid(from[i]));
    if (problem.leave[i] > 0.0) change += problem.leave[i] * (logSigmoid(-to[i]) - logSigmoid(-from[i]));
  }
  const CellNeighbours& graph = *problem.graph;
  double pairs = 0.0;
  for (std::size_t i = 0; i + 1 < graph.offsets.size(); ++i) {
    for (std::uint32_t k = graph.offsets[i]; k < graph.offsets[i + 1]; ++k) {
      const std::uint32_t j = graph.indices[k];
      if (j <= i) continue;
      const double before = from[i] - from[j];
      const double after = to[i] - to[j];
      pairs += (after - before) * (after + before);
    }
  }
  return change - problem.inverse_temperature * pairs;
}

int maximizeMrfMap(const MrfMapProblem& problem, std::vector<double>& logits, int max_newton_iterations,
                   double gain_tolerance) {
  check(problem, logits);
  if (!(std::isfinite(gain_tolerance) && gain_tolerance >= 0.0)) {
    throw std::invalid_argument("MRF: the gain tolerance must be finite and >= 0");
  }
  const std::size_t n = logits.size();
  if (n == 0) return 0;
  for (double& l : logits) l = std::clamp(l, problem.lo, problem.hi);
  const double two_lambda = 2.0 * problem.inverse_temperature;
  std::vector<double> degree(n);
  for (std::size_t i = 0; i < n; ++i) {
    degree[i] = static_cast<double>(problem.graph->offsets[i + 1] - problem.graph->offsets[i]);
  }

  std::vector<double> h(n), step(n), residual(n), direction(n), product(n), preconditioned(n), trial(n);
  std::vector<char> free(n);
  const auto precondition = [&](const std::vector<double>& r, std::vector<double>& z) {
    for (std::size_t i = 0; i < n; ++i) z[i] = free[i] ? r[i] / (h[i] + two_lambda * degree[i]) : 0.0;
  };
  // Backtracking along the projected path from `logits` in direction `step` (Armijo, with the
  // objective's change computed term by term); true if a point that gains was found.
  const auto line_search = [&](const std::vector<double>& gradient) {
    double t = 1.0;
    for (int halving = 0; halving < 60; ++halving, t *= 0.5) {
      double predicted = 0.0;
      for (std::size_t i = 0; i < n; ++i) {
        trial[i] = std::clamp(logits[i] + t * step[i], problem.lo, problem.hi);
        predicted += gradient[i] * (trial[i] - logits[i]);
      }
      // A clipped long step may predict nothing where a shorter one gains: keep halving.
      if (!(predicted > 0.0)) continue;
      const double change = mrfMapObjectiveChange(problem, logits, trial);
      if (change > 0.0 && change >= 1e-4 * predicted) return true;
    }
    return false;
  };
  double forcing = 0.1;
  int iteration = 0;
  while (iteration < max_newton_iterations) {
    const std::vector<double> gradient = mrfMapGradient(problem, logits);
    // -Hessian = diag(h) + 2 lambda L; a tiny ridge keeps cells without counts and without
    // neighbours (h = 0, nothing pulling) from making the system singular: they do not move.
    for (std::size_t i = 0; i < n; ++i) {
      h[i] = (problem.stay[i] + problem.leave[i]) * sigmoid(logits[i]) * sigmoid(-logits[i]) + 1e-12;
    }
    // Projected Newton: a variable at a bound whose gradient points outwards stays there.
    bool any_free = false;
    for (std::size_t i = 0; i < n; ++i) {
      free[i] = !((logits[i] <= problem.lo && gradient[i] < 0.0) || (logits[i] >= problem.hi && gradient[i] > 0.0));
      any_free = any_free || (free[i] && gradient[i] != 0.0);
    }
    if (!any_free) break;
    // Conjugate gradients for (-H)_FF step = gradient_F, Jacobi-preconditioned, solved only
    // as precisely as the last Newton step was large (inexact Newton: superlinear, and the
    // early steps cost a few CG iterations instead of hundreds).
    std::fill(step.begin(), step.end(), 0.0);
    for (std::size_t i = 0; i < n; ++i) residual[i] = free[i] ? gradient[i] : 0.0;
    precondition(residual, preconditioned);
    direction = preconditioned;
    double rz = dot(residual, preconditioned);
    // Measured in the preconditioned norm (each equation scaled by its diagonal), so that a
    // weakly tied cell's equation counts as much as a heavily observed one's.
    const double stop = forcing * forcing * rz;
    for (std::size_t cg = 0; cg < 4 * n + 20 && rz > stop; ++cg) {
      applySystem(*problem.graph, h, two_lambda, free, direction, product);
      const double curvature = dot(direction, product);
      if (!(curvature > 0.0)) break;
      const double alpha = rz / curvature;
      for (std::size_t i = 0; i < n; ++i) {
        step[i] += alpha * direction[i];
        residual[i] -= alpha * product[i];
      }
      precondition(residual, preconditioned);
      const double rz_next = dot(residual, preconditioned);
      const double beta = rz_next / rz;
      rz = rz_next;
      for (std::size_t i = 0; i < n; ++i) direction[i] = preconditioned[i] + beta * direction[i];
    }
    // Converged when the Newton step itself (coupling included, so a shift of all logits
    // together, which costs no smoothing, is measured right) is below 1e-6 in logits, or when
    // the gain it predicts is at most gain_tolerance; that last step is still taken, which
    // with Newton's quadratic convergence leaves an error far below it. An M-step inside EM
    // needs no more: the next E-step moves the counts.
    double largest_step = 0.0;
    // The step's gain on the quadratic model, g.s / 2 (= s.(-H)s / 2 on the free variables,
    // CG starting from 0): for an inexact CG step a lower bound of the full Newton step's.
    double predicted_gain = 0.0;
    for (std::size_t i = 0; i < n; ++i) {
      largest_step = std::max(largest_step, std::abs(step[i]));
      predicted_gain += 0.5 * gradient[i] * step[i];
    }
    if (largest_step <= 1e-13) break;
    const bool last = largest_step <= 1e-6 || (gain_tolerance > 0.0 && predicted_gain <= gain_tolerance);
    forcing = std::min(0.1, largest_step);
    ++iteration;
    bool gained = line_search(gradient);
    if (!gained) {
      // The Newton direction found no gain (rounding, or a degenerate system): fall back to
      // the preconditioned gradient once before giving up.
      precondition(gradient, step);
      gained = line_search(gradient);
    }
    if (gained) logits.swap(trial);
    if (!gained || last) break;
  }
  return iteration;
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
