#pragma once
// The M-step of MRF-smoothed offline EM (Li, Barão & Rato; THEORY.md §7) for one parameter
// map: over the logits l_c of one transition probability per cell (p(occ -> occ) or
// p(free -> free)), maximise
//
//   F(l) = sum_c [ stay_c log sigma(l_c) + leave_c log sigma(-l_c) ]
//          - (1 / T) * sum over 8-neighbour pairs {c, c'} of (l_c - l_c')^2
//
// subject to lo <= l_c <= hi (the probability bounds). stay_c and leave_c are the expected
// counts of staying in / leaving the state (E-step, plus MAP pseudo-counts). F is concave:
// projected Newton steps, each solving the sparse system (diag(h) + (2 / T) L) d = g by
// Jacobi-preconditioned conjugate gradients (L the graph Laplacian), with a backtracking line
// search. runOfflineEm (offline_em.h) uses it when OfflineEmConfig::mrf_temperature > 0.
//
// ROS-free: standard library only.

#include <cstdint>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/traversal.h"

namespace dynamic_occupancy_grid {
namespace core {

/// The 8-neighbour graph of a set of cells, in compressed rows: the neighbours of cell i are
/// indices[offsets[i] .. offsets[i + 1]), in increasing order.
struct CellNeighbours {
  std::vector<std::uint32_t> offsets{0};
  std::vector<std::uint32_t> indices;
  std::size_t pairs() const { return indices.size() / 2; }
};
/// Neighbours among `cells` (distinct cells; throws std::invalid_argument for a repeated one).
CellNeighbours eightNeighbours(const std::vector<CellXY>& cells);

struct MrfMapProblem {
  const CellNeighbours* graph = nullptr;
  std::vector<double> stay;   ///< >= 0 per cell
  std::vector<double> leave;  ///< >= 0 per cell
  double inverse_temperature = 0.0;  ///< 1 / T; 0 decouples the cells (plain EM)
  double lo = -30.0;          ///< bounds of the logits (finite)
  double hi = 30.0;
};

/// F(l) above.
double mrfMapObjective(const MrfMapProblem& problem, const std::vector<double>& logits);
/// dF/dl.
std::vector<double> mrfMapGradient(const MrfMapProblem& problem, const std::vector<double>& logits);
/// The MRF prior term alone: -(1 / T) * sum over pairs of (l_c - l_c')^2.
double mrfPrior(const CellNeighbours& graph, double inverse_temperature, const std::vector<double>& logits);

/// F(to) - F(from), computed term by term (exact where F's own rounding is not).
double mrfMapObjectiveChange(const MrfMapProblem& problem, const std::vector<double>& from,
                             const std::vector<double>& to);

/// Maximises F from `logits` (clamped to the bounds first) and leaves the maximiser there;
/// returns the Newton iterations used (at most max_newton_iterations). Stops after taking a
/// Newton step below 1e-6 in logits (quadratic convergence leaves far less), or, with
/// gain_tolerance > 0, one whose predicted gain on the quadratic model (gradient . step / 2,
/// for the inexact CG step a lower bound of the full Newton step's) is at most
/// gain_tolerance nats (EM's M-step needs no more than a fraction of EM's own tolerance), or
/// when neither it nor the preconditioned gradient gains any more (rounding). Throws
/// std::invalid_argument for inconsistent sizes, negative counts, bounds that are not finite
/// and ordered, or a gain tolerance that is negative or not finite.
int maximizeMrfMap(const MrfMapProblem& problem, std::vector<double>& logits, int max_newton_iterations = 100,
                   double gain_tolerance = 0.0);

}  // namespace core
}  // namespace dynamic_occupancy_grid
