// Tests of the A* grid planner (evaluation/planner.h). The reference is a plain breadth-first
// search (every move costs 1, so BFS distances are the shortest path lengths), written
// from the header's promises and sharing no code with the planner.

#include "dynamic_occupancy_grid/evaluation/planner.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstdlib>
#include <deque>
#include <random>
#include <stdexcept>
#include <vector>

namespace dog = dynamic_occupancy_grid::core;
namespace evaluation = dynamic_occupancy_grid::evaluation;

namespace {

constexpr int kUnreachable = -1;

// Moves from start to goal by BFS, kUnreachable if none. Like the planner, the start cell's
// own flag does not matter and a blocked goal cannot be entered.
int bfsDistance(const evaluation::BlockedGrid& grid, dog::CellXY start, dog::CellXY goal) {
  std::vector<int> distance(static_cast<std::size_t>(grid.width() * grid.height()), kUnreachable);
  std::deque<dog::CellXY> queue{start};
  distance[grid.index(start.x, start.y)] = 0;
  while (!queue.empty()) {
    const dog::CellXY cell = queue.front();
    queue.pop_front();
    if (cell == goal) return distance[grid.index(cell.x, cell.y)];
    const dog::CellXY neighbours[4] = {
        {cell.x + 1, cell.y}, {cell.x - 1, cell.y}, {cell.x, cell.y + 1}, {cell.x, cell.y - 1}};
    for (const dog::CellXY& next : neighbours) {
      if (!grid.inside(next.x, next.y) || grid.blocked(next.x, next.y)) continue;
      int& d = distance[grid.index(next.x, next.y)];
      if (d != kUnreachable) continue;
      d = distance[grid.index(cell.x, cell.y)] + 1;
      queue.push_back(next);
    }
  }
  return kUnreachable;
}

// A path is valid when it runs from start to goal through 4-neighbours and enters no
// blocked cell (the start itself excepted).
::testing::AssertionResult isValidPath(const evaluation::BlockedGrid& grid, const std::vector<dog::CellXY>& path,
                                       dog::CellXY start, dog::CellXY goal) {
  if (path.empty()) return ::testing::AssertionFailure() << "empty path";
  if (path.front() != start) return ::testing::AssertionFailure() << "does not begin at the start";
  if (path.back() != goal) return ::testing::AssertionFailure() << "does not end at the goal";
  for (std::size_t i = 1; i < path.size(); ++i) {
    const int step = std::abs(path[i].x - path[i - 1].x) + std::abs(path[i].y - path[i - 1].y);
    if (step != 1) return ::testing::AssertionFailure() << "move " << i << " is not to a 4-neighbour";
    if (grid.blocked(path[i].x, path[i].y)) {
      return ::testing::AssertionFailure() << "cell " << i << " (" << path[i].x << ", " << path[i].y
                                           << ") is blocked";
    }
  }
  return ::testing::AssertionSuccess();
}

evaluation::BlockedGrid randomGrid(std::mt19937& rng, std::int32_t width, std::int32_t height, double density) {
  evaluation::BlockedGrid grid(width, height);
  std::bernoulli_distribution blocked(density);
  for (std::int32_t y = 0; y < height; ++y) {
    for (std::int32_t x = 0; x < width; ++x) grid.setBlocked(x, y, blocked(rng));
  }
  return grid;
}

}  // namespace

TEST(AStarPlanner, MatchesBreadthFirstSearchOnRandomGrids) {
  std::mt19937 rng(12345);
  evaluation::AStarPlanner planner;  // one planner for all cases: reused buffers must not leak state
  int reachable = 0;
  int unreachable = 0;
  for (const std::int32_t width : {1, 2, 7, 30}) {
    for (const std::int32_t height : {1, 3, 15, 31}) {
      for (const double density : {0.0, 0.2, 0.35, 0.5}) {
        for (int trial = 0; trial < 20; ++trial) {
          const evaluation::BlockedGrid grid = randomGrid(rng, width, height, density);
          std::uniform_int_distribution<std::int32_t> px(0, width - 1);
          std::uniform_int_distribution<std::int32_t> py(0, height - 1);
          const dog::CellXY start{px(rng), py(rng)};
          const dog::CellXY goal{px(rng), py(rng)};
          const int expected = bfsDistance(grid, start, goal);
          const std::vector<dog::CellXY> path = planner.plan(grid, start, goal);
          SCOPED_TRACE(::testing::Message() << width << "x" << height << " density " << density << " trial "
                                            << trial);
          if (expected == kUnreachable) {
            EXPECT_TRUE(path.empty());
            ++unreachable;
          } else {
            ASSERT_TRUE(isValidPath(grid, path, start, goal));
            EXPECT_EQ(static_cast<int>(path.size()) - 1, expected);
            ++reachable;
          }
        }
      }
    }
  }
  // The sweep must exercise both outcomes, or it proves less than it seems to.
  EXPECT_GT(reachable, 300);
  EXPECT_GT(unreachable, 100);
}

TEST(AStarPlanner, StartEqualsGoal) {
  evaluation::BlockedGrid grid(4, 3);
  evaluation::AStarPlanner planner;
  const std::vector<dog::CellXY> path = planner.plan(grid, {2, 1}, {2, 1});
  ASSERT_EQ(path.size(), 1U);
  EXPECT_EQ(path[0], (dog::CellXY{2, 1}));
  // Also when the robot's own cell is marked blocked (a map may believe so).
  grid.setBlocked(2, 1, true);
  EXPECT_EQ(planner.plan(grid, {2, 1}, {2, 1}).size(), 1U);
}

TEST(AStarPlanner, BlockedGoalIsUnreachable) {
  evaluation::BlockedGrid grid(5, 5);
  grid.setBlocked(4, 4, true);
  evaluation::AStarPlanner planner;
  EXPECT_TRUE(planner.plan(grid, {0, 0}, {4, 4}).empty());
}

TEST(AStarPlanner, BlockedStartIsLeft) {
  evaluation::BlockedGrid grid(5, 1);
  grid.setBlocked(0, 0, true);
  evaluation::AStarPlanner planner;
  const std::vector<dog::CellXY> path = planner.plan(grid, {0, 0}, {4, 0});
  EXPECT_EQ(path.size(), 5U);
}

TEST(AStarPlanner, WallWithoutGapIsUnreachable) {
  evaluation::BlockedGrid grid(7, 5);
  for (std::int32_t y = 0; y < 5; ++y) grid.setBlocked(3, y, true);
  evaluation::AStarPlanner planner;
  EXPECT_TRUE(planner.plan(grid, {0, 2}, {6, 2}).empty());
  // One gap, at the far end: the path must go round through it.
  grid.setBlocked(3, 4, false);
  const std::vector<dog::CellXY> path = planner.plan(grid, {0, 2}, {6, 2});
  ASSERT_TRUE(isValidPath(grid, path, {0, 2}, {6, 2}));
  EXPECT_EQ(path.size() - 1, 10U);  // 6 across plus 2 up and 2 down
}

TEST(AStarPlanner, TakesTheDetourOnlyWhenTheShortCutIsBlocked) {
  // The door scenario in miniature: a corridor at y = 2 with a door at (3, 2), and a
  // detour along y = 0 joined by the columns x = 0 and x = 6.
  evaluation::BlockedGrid grid(7, 3);
  for (std::int32_t x = 1; x <= 5; ++x) grid.setBlocked(x, 1, true);
  evaluation::AStarPlanner planner;
  EXPECT_EQ(planner.plan(grid, {0, 2}, {6, 2}).size() - 1, 6U);
  grid.setBlocked(3, 2, true);
  EXPECT_EQ(planner.plan(grid, {0, 2}, {6, 2}).size() - 1, 10U);
}

TEST(AStarPlanner, DeterministicWhateverWasPlannedBefore) {
  // An open grid has many shortest paths: the chosen one must not depend on the history
  // of the planner's buffers.
  const evaluation::BlockedGrid open(9, 9);
  evaluation::AStarPlanner fresh;
  const std::vector<dog::CellXY> first = fresh.plan(open, {0, 0}, {8, 8});

  std::mt19937 rng(7);
  evaluation::AStarPlanner used;
  for (int i = 0; i < 50; ++i) {
    const evaluation::BlockedGrid other = randomGrid(rng, 9, 9, 0.3);
    used.plan(other, {0, 0}, {8, 8});
  }
  EXPECT_EQ(used.plan(open, {0, 0}, {8, 8}), first);
  EXPECT_EQ(fresh.plan(open, {0, 0}, {8, 8}), first);
}

TEST(AStarPlanner, GridSizeChangesBetweenCalls) {
  evaluation::AStarPlanner planner;
  EXPECT_EQ(planner.plan(evaluation::BlockedGrid(30, 15), {1, 13}, {28, 13}).size() - 1, 27U);
  EXPECT_EQ(planner.plan(evaluation::BlockedGrid(3, 2), {0, 0}, {2, 1}).size() - 1, 3U);
  EXPECT_EQ(planner.plan(evaluation::BlockedGrid(30, 15), {0, 0}, {29, 14}).size() - 1, 43U);
}

TEST(AStarPlanner, RejectsEndpointsOutsideTheGrid) {
  const evaluation::BlockedGrid grid(4, 4);
  evaluation::AStarPlanner planner;
  EXPECT_THROW(planner.plan(grid, {-1, 0}, {3, 3}), std::out_of_range);
  EXPECT_THROW(planner.plan(grid, {0, 0}, {4, 3}), std::out_of_range);
}

TEST(BlockedGrid, OutsideIsBlockedAndSizeIsChecked) {
  evaluation::BlockedGrid grid(3, 2);
  EXPECT_FALSE(grid.blocked(2, 1));
  EXPECT_TRUE(grid.blocked(3, 1));
  EXPECT_TRUE(grid.blocked(0, -1));
  EXPECT_THROW(grid.setBlocked(3, 0, true), std::out_of_range);
  EXPECT_THROW(evaluation::BlockedGrid(0, 5), std::invalid_argument);
  EXPECT_THROW(evaluation::BlockedGrid(5, -1), std::invalid_argument);
}
