#include "dynamic_occupancy_grid/evaluation/planner.h"

#include <algorithm>
#include <cstdlib>
#include <functional>
#include <stdexcept>
#include <string>

namespace dynamic_occupancy_grid {
namespace evaluation {

BlockedGrid::BlockedGrid(std::int32_t width, std::int32_t height) : width_(width), height_(height) {
  if (width <= 0 || height <= 0) throw std::invalid_argument("BlockedGrid: width and height must be positive");
  blocked_.assign(static_cast<std::size_t>(width) * static_cast<std::size_t>(height), 0);
}

void BlockedGrid::setBlocked(std::int32_t x, std::int32_t y, bool blocked) {
  if (!inside(x, y)) {
    throw std::out_of_range("BlockedGrid::setBlocked: cell (" + std::to_string(x) + ", " + std::to_string(y) +
                            ") is outside the grid");
  }
  blocked_[index(x, y)] = blocked ? 1 : 0;
}

void AStarPlanner::prepare(std::size_t cells) {
  if (stamp_.size() != cells) {
    stamp_.assign(cells, 0);
    cost_.assign(cells, 0);
    parent_.assign(cells, -1);
    closed_.assign(cells, 0);
    generation_ = 0;
  }
  ++generation_;
  if (generation_ == 0) {
    // The counter wrapped: stale stamps could match again, so clear them once.
    std::fill(stamp_.begin(), stamp_.end(), 0);
    generation_ = 1;
  }
  open_.clear();
}

std::vector<core::CellXY> AStarPlanner::plan(const BlockedGrid& grid, core::CellXY start, core::CellXY goal) {
  if (!grid.inside(start.x, start.y) || !grid.inside(goal.x, goal.y)) {
    throw std::out_of_range("AStarPlanner::plan: start or goal is outside the grid");
  }
  if (start == goal) return {start};
  if (grid.blocked(goal.x, goal.y)) return {};

  const std::size_t cells = static_cast<std::size_t>(grid.width()) * static_cast<std::size_t>(grid.height());
  prepare(cells);
  const auto heuristic = [&goal](std::int32_t x, std::int32_t y) {
    return std::abs(goal.x - x) + std::abs(goal.y - y);
  };
  const auto visit = [this](std::int32_t index, std::int32_t cost, std::int32_t parent) {
    stamp_[index] = generation_;
    cost_[index] = cost;
    parent_[index] = parent;
    closed_[index] = 0;
  };

  const std::int32_t width = grid.width();
  const std::int32_t start_index = static_cast<std::int32_t>(grid.index(start.x, start.y));
  const std::int32_t goal_index = static_cast<std::int32_t>(grid.index(goal.x, goal.y));
  visit(start_index, 0, -1);
  const std::int32_t start_h = heuristic(start.x, start.y);
  const auto push = [this](const OpenEntry& entry) {
    open_.push_back(entry);
    std::push_heap(open_.begin(), open_.end(), std::greater<OpenEntry>());
  };
  push(OpenEntry{start_h, start_h, start_index});

  constexpr std::int32_t kDx[4] = {1, -1, 0, 0};
  constexpr std::int32_t kDy[4] = {0, 0, 1, -1};
  bool found = false;
  while (!open_.empty()) {
    std::pop_heap(open_.begin(), open_.end(), std::greater<OpenEntry>());
    const OpenEntry entry = open_.back();
    open_.pop_back();
    // Lazy deletion: a cell is pushed again when its cost improves; older entries are stale.
    if (closed_[entry.index] != 0) continue;
    closed_[entry.index] = 1;
    if (entry.index == goal_index) {
      found = true;
      break;
    }
    const std::int32_t x = entry.index % width;
    const std::int32_t y = entry.index / width;
    const std::int32_t next_cost = cost_[entry.index] + 1;
    for (int k = 0; k < 4; ++k) {
      const std::int32_t nx = x + kDx[k];
      const std::int32_t ny = y + kDy[k];
      if (grid.blocked(nx, ny)) continue;
      const std::int32_t next = static_cast<std::int32_t>(grid.index(nx, ny));
      if (stamp_[next] == generation_ && (closed_[next] != 0 || cost_[next] <= next_cost)) continue;
      visit(next, next_cost, entry.index);
      const std::int32_t h = heuristic(nx, ny);
      push(OpenEntry{next_cost + h, h, next});
    }
  }
  if (!found) return {};

  std::vector<core::CellXY> path(static_cast<std::size_t>(cost_[goal_index]) + 1);
  std::int32_t index = goal_index;
  for (auto it = path.rbegin(); it != path.rend(); ++it) {
    *it = core::CellXY{index % width, index / width};
    index = parent_[index];
  }
  return path;
}

}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
