#pragma once
// A* on a 4-connected grid of free and blocked cells: the planner of the AAAI paper's path
// planning experiment (Meyer-Delius et al. 2012, "Path Planning": cost 1 to enter a free
// cell, infinite for an occupied one after clipping the occupancy at 0.5). It is called
// on every step of a simulated robot, so its buffers are kept from call to call.
//
// ROS-free: standard library only.

#include <cstdint>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/traversal.h"

namespace dynamic_occupancy_grid {
namespace evaluation {

/// Which cells of a width x height grid a robot may not enter (row-major, index = y * width
/// + x); cells outside the grid are blocked.
class BlockedGrid {
 public:
  /// All cells free. Throws std::invalid_argument for a non-positive size.
  BlockedGrid(std::int32_t width, std::int32_t height);

  std::int32_t width() const { return width_; }
  std::int32_t height() const { return height_; }
  bool inside(std::int32_t x, std::int32_t y) const { return x >= 0 && y >= 0 && x < width_ && y < height_; }
  std::size_t index(std::int32_t x, std::int32_t y) const {
    return static_cast<std::size_t>(y) * static_cast<std::size_t>(width_) + static_cast<std::size_t>(x);
  }
  bool blocked(std::int32_t x, std::int32_t y) const { return !inside(x, y) || blocked_[index(x, y)] != 0; }
  /// Throws std::out_of_range for a cell outside the grid.
  void setBlocked(std::int32_t x, std::int32_t y, bool blocked);

 private:
  std::int32_t width_;
  std::int32_t height_;
  std::vector<std::uint8_t> blocked_;
};

/// A* with the Manhattan distance as heuristic (consistent for unit moves, so every cell is
/// expanded at most once and the first path found is a shortest one).
///
/// Deterministic: the open list is ordered by (f, h, cell index), a strict total order, and
/// neighbours are generated in the fixed order +x, -x, +y, -y; the same grid and endpoints
/// always give the same path, whatever was planned before.
class AStarPlanner {
 public:
  /// A shortest path from `start` to `goal`, both included ({start} when they are equal),
  /// every move to one of the 4 neighbours; empty when no path exists. The start cell's own
  /// flag is ignored (the robot stands there); a blocked goal is unreachable. Throws
  /// std::out_of_range when start or goal is outside the grid.
  std::vector<core::CellXY> plan(const BlockedGrid& grid, core::CellXY start, core::CellXY goal);

 private:
  struct OpenEntry {
    std::int32_t f;
    std::int32_t h;
    std::int32_t index;
    bool operator>(const OpenEntry& other) const {
      if (f != other.f) return f > other.f;
      if (h != other.h) return h > other.h;
      return index > other.index;
    }
  };

  void prepare(std::size_t cells);

  // Per cell, valid only where stamp == generation_: a new search costs nothing to reset.
  std::vector<std::uint32_t> stamp_;
  std::vector<std::int32_t> cost_;    ///< g: moves from the start
  std::vector<std::int32_t> parent_;  ///< cell index the best path comes from, -1 at the start
  std::vector<std::uint8_t> closed_;
  std::uint32_t generation_ = 0;
  std::vector<OpenEntry> open_;  ///< a min-heap (std::push_heap with std::greater), capacity kept
};

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
