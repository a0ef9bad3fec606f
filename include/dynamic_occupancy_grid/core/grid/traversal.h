#pragma once
// Exact 2D grid traversal of a segment (Amanatides & Woo, with the crossing order decided
// by an exact-in-spirit cross-multiplied error term instead of accumulated t values).
//
// Cells are half-open squares [ix, ix + 1) x [iy, iy + 1) in grid units (one unit = one
// cell). The traversal visits exactly the cells that contain at least one point of the
// closed segment, each once, in order from the start to the end:
//   - along a grid line x = k only the cells of column k are visited (never both sides);
//   - through a corner, a diagonal step when both coordinates grow or both shrink, otherwise
//     the one cell the corner point itself lies in, then the diagonal neighbour.
// For inputs whose coordinates are short dyadic fractions (as in the tests) the arithmetic
// is exact; for other inputs a crossing closer than rounding to a corner may be ordered
// either way, which still yields a connected, duplicate-free path.

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <limits>

namespace dynamic_occupancy_grid {
namespace core {

struct CellXY {
  std::int32_t x = 0;
  std::int32_t y = 0;
  bool operator==(const CellXY& other) const { return x == other.x && y == other.y; }
  bool operator!=(const CellXY& other) const { return !(*this == other); }
};

/// Calls visit_before_end(x, y) for every cell of the segment (u0, v0) -> (u1, v1) except
/// the end cell, in order, and returns the end cell (the one holding (u1, v1)), which the
/// caller marks as hit or missed. Inputs are finite grid coordinates whose floors fit in
/// int32 (the caller guarantees both).
template <class Visitor>
CellXY traverseSegment(double u0, double v0, double u1, double v1, Visitor&& visit_before_end) {
  std::int32_t ix = static_cast<std::int32_t>(std::floor(u0));
  std::int32_t iy = static_cast<std::int32_t>(std::floor(v0));
  const std::int32_t end_x = static_cast<std::int32_t>(std::floor(u1));
  const std::int32_t end_y = static_cast<std::int32_t>(std::floor(v1));
  const double du = u1 - u0;
  const double dv = v1 - v0;
  const std::int32_t step_x = du > 0.0 ? 1 : -1;
  const std::int32_t step_y = dv > 0.0 ? 1 : -1;
  const double abs_du = std::abs(du);
  const double abs_dv = std::abs(dv);

  // Distance along each axis to the next crossing. Moving up, the crossing is at the next
  // integer, and a point on it already belongs to the next cell. Moving down, the crossing
  // is at the cell's own lower edge (distance 0 when starting on it) and the point on it
  // still belongs to the current cell: the step happens just after.
  const double dist_x = du > 0.0 ? (ix + 1.0 - u0) : (u0 - ix);
  const double dist_y = dv > 0.0 ? (iy + 1.0 - v0) : (v0 - iy);
  // Sign of t_x - t_y, cross-multiplied to avoid divisions:
  //   error = dist_x * |dv| - dist_y * |du|  (< 0: x crosses first).
  // An axis without motion never crosses: +-infinity keeps the other axis stepping.
  constexpr double kInf = std::numeric_limits<double>::infinity();
  double error = abs_du == 0.0 ? kInf : (abs_dv == 0.0 ? -kInf : dist_x * abs_dv - dist_y * abs_du);

  std::int32_t remaining_x = std::abs(end_x - ix);
  std::int32_t remaining_y = std::abs(end_y - iy);
  while (remaining_x + remaining_y > 0) {
    visit_before_end(ix, iy);
    // The remaining counts guard the end: rounding may never push the path past it.
    bool move_x;
    bool move_y;
    if (remaining_y == 0) {
      move_x = true;
      move_y = false;
    } else if (remaining_x == 0) {
      move_x = false;
      move_y = true;
    } else if (error < 0.0) {
      move_x = true;
      move_y = false;
    } else if (error > 0.0) {
      move_x = false;
      move_y = true;
    } else if (step_x == step_y) {
      // Through a corner with both coordinates growing (or both shrinking): the corner point
      // belongs to the diagonal cell (or to the current one): one diagonal step.
      move_x = true;
      move_y = true;
    } else {
      // Through a corner with one coordinate growing and the other shrinking: the corner
      // point lies in the cell reached by the growing coordinate first.
      move_x = step_x > 0;
      move_y = !move_x;
    }
    if (move_x) {
      ix += step_x;
      --remaining_x;
      error += abs_dv;
    }
    if (move_y) {
      iy += step_y;
      --remaining_y;
      error -= abs_du;
    }
  }
  return CellXY{ix, iy};
}

}  // namespace core
}  // namespace dynamic_occupancy_grid
