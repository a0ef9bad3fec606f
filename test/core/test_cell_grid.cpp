// Tests of the tiled cell storage (core/grid/cell_grid.h) and of the map geometry the mapper
// builds on it: world <-> lattice coordinates, the map window, row-major layer layout,
// growth in whole 64 x 64 tiles (also towards negative coordinates), fixed bounds, the map
// size limit, and the memory per cell.
//
// References are written out independently in this file: floor division / modulo by 64 in
// plain integer arithmetic, a std::map of every value written, hand-computed cell indices.

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <stdexcept>
#include <utility>
#include <vector>

#include "dynamic_occupancy_grid/core/layers/layers.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/grid/scan.h"

namespace dog = dynamic_occupancy_grid::core;

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr std::int32_t kNoLimit = 1 << 20;  // cells per side, far beyond what tests touch

dog::CellGrid::CellDefaults defaults() { return dog::CellGrid::CellDefaults{0.125f, 0.25f}; }

dog::CellBox box(std::int32_t min_x, std::int32_t min_y, std::int32_t max_x, std::int32_t max_y) {
  dog::CellBox b;
  b.min_x = min_x;
  b.min_y = min_y;
  b.max_x = max_x;
  b.max_y = max_y;
  return b;
}

void expectBoxEq(const dog::CellBox& actual, const dog::CellBox& expected) {
  EXPECT_EQ(actual.min_x, expected.min_x);
  EXPECT_EQ(actual.min_y, expected.min_y);
  EXPECT_EQ(actual.max_x, expected.max_x);
  EXPECT_EQ(actual.max_y, expected.max_y);
}

// Floor division and modulo by 64, written without shifts.
std::int32_t floorDiv64(std::int32_t v) {
  std::int32_t q = v / 64;
  if (v % 64 != 0 && v < 0) --q;
  return q;
}
std::int32_t floorMod64(std::int32_t v) { return v - 64 * floorDiv64(v); }

// Marks cell (x, y) observed with the given state, going through the grid's public API.
dog::CellGrid::Tile* writeCell(dog::CellGrid& grid, std::int32_t x, std::int32_t y, float p_occ,
                               std::int32_t last_step, float log_odds, float p_of, float p_fo) {
  grid.reserve(box(x, y, x, y));
  dog::CellGrid::Tile* tile = grid.tileForWriting(x, y);
  if (tile == nullptr) return nullptr;
  const int i = dog::CellGrid::offsetOf(x, y);
  tile->p_occ[i] = p_occ;
  tile->last_step[i] = last_step;
  tile->log_odds[i] = log_odds;
  tile->p_occ_given_free[i] = p_of;
  tile->p_free_given_occ[i] = p_fo;
  return tile;
}

struct Stored {
  float p_occ;
  std::int32_t last_step;
  float log_odds;
  float p_of;
  float p_fo;
};

}  // namespace

// =====================================================================================
// CellBox
// =====================================================================================

TEST(CellBox, EmptyIncludeContainsExtent) {
  dog::CellBox b;
  EXPECT_TRUE(b.empty());
  EXPECT_EQ(b.width(), 0);
  EXPECT_EQ(b.height(), 0);
  EXPECT_FALSE(b.contains(0, 0));
  b.include(3, -2);
  EXPECT_FALSE(b.empty());
  EXPECT_EQ(b.width(), 1);
  EXPECT_EQ(b.height(), 1);
  EXPECT_TRUE(b.contains(3, -2));
  b.include(-4, 5);
  expectBoxEq(b, box(-4, -2, 3, 5));
  EXPECT_EQ(b.width(), 8);
  EXPECT_EQ(b.height(), 8);
  EXPECT_TRUE(b.contains(-4, 5));
  EXPECT_TRUE(b.contains(0, 0));
  EXPECT_FALSE(b.contains(4, 0));
  EXPECT_FALSE(b.contains(0, -3));
  // Including an empty box changes nothing; including a box takes the union.
  b.include(dog::CellBox{});
  expectBoxEq(b, box(-4, -2, 3, 5));
  b.include(box(10, 10, 12, 11));
  expectBoxEq(b, box(-4, -2, 12, 11));
  // The full int32 range does not overflow width().
  const dog::CellBox huge = box(std::numeric_limits<std::int32_t>::min(), 0,
                                std::numeric_limits<std::int32_t>::max(), 0);
  EXPECT_EQ(huge.width(), std::int64_t{1} << 32);
}

// =====================================================================================
// Geometry: world <-> lattice, tile addressing, window
// =====================================================================================

TEST(CellGridGeometry, WorldToLatticeUsesAnchorAndResolution) {
  const dog::CellGrid grid(0.25, 1.5, -2.25, std::nullopt, kNoLimit, defaults());
  EXPECT_EQ(grid.resolution(), 0.25);
  EXPECT_EQ(grid.anchorX(), 1.5);
  EXPECT_EQ(grid.anchorY(), -2.25);
  EXPECT_DOUBLE_EQ(grid.toLatticeX(1.5), 0.0);
  EXPECT_DOUBLE_EQ(grid.toLatticeY(-2.25), 0.0);
  EXPECT_DOUBLE_EQ(grid.toLatticeX(1.625), 0.5);   // (1.625 - 1.5) / 0.25
  EXPECT_DOUBLE_EQ(grid.toLatticeX(1.0), -2.0);    // (1.0 - 1.5) / 0.25
  EXPECT_DOUBLE_EQ(grid.toLatticeY(-2.5), -1.0);   // (-2.5 + 2.25) / 0.25
  EXPECT_DOUBLE_EQ(grid.toLatticeY(0.0), 9.0);     // 2.25 / 0.25
  EXPECT_DOUBLE_EQ(grid.toLatticeX(-14.5), -64.0);
  // Random points: lattice = (world - anchor) / resolution.
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-500.0, 500.0);
  const dog::CellGrid g2(0.05, -3.0, 7.0, std::nullopt, kNoLimit, defaults());
  for (int i = 0; i < 1000; ++i) {
    const double x = u(rng);
    const double y = u(rng);
    ASSERT_NEAR(g2.toLatticeX(x), (x + 3.0) / 0.05, 1e-9 * (1.0 + std::fabs(x) / 0.05));
    ASSERT_NEAR(g2.toLatticeY(y), (y - 7.0) / 0.05, 1e-9 * (1.0 + std::fabs(y) / 0.05));
  }
}

TEST(CellGridGeometry, OffsetAndTileCoordinatesFloorForNegativeCells) {
  // Hand-computed: cell (-1, -1) is the last cell (63, 63) of tile (-1, -1).
  EXPECT_EQ(dog::CellGrid::offsetOf(-1, -1), 63 * 64 + 63);
  EXPECT_EQ(dog::CellGrid::offsetOf(0, 0), 0);
  EXPECT_EQ(dog::CellGrid::offsetOf(64, 1), 64);        // (0, 1) in tile (1, 0)
  EXPECT_EQ(dog::CellGrid::offsetOf(-64, -65), 63 * 64);  // (0, 63) in tile (-1, -2)
  std::mt19937_64 rng(17);
  std::uniform_int_distribution<std::int32_t> coord(-100000, 100000);
  dog::CellGrid grid(1.0, 0.0, 0.0, std::nullopt, kNoLimit, defaults());
  for (int i = 0; i < 300; ++i) {
    const std::int32_t x = coord(rng);
    const std::int32_t y = coord(rng);
    const int offset = dog::CellGrid::offsetOf(x, y);
    ASSERT_EQ(offset, floorMod64(y) * 64 + floorMod64(x)) << x << ", " << y;
    grid.reserve(box(x, y, x, y));
    const dog::CellGrid::Tile* tile = grid.tileForWriting(x, y);
    ASSERT_NE(tile, nullptr);
    ASSERT_EQ(tile->tile_x, floorDiv64(x)) << x;
    ASSERT_EQ(tile->tile_y, floorDiv64(y)) << y;
    ASSERT_EQ(tile->cellX(offset), x);
    ASSERT_EQ(tile->cellY(offset), y);
    ASSERT_EQ(grid.findTile(x, y), tile);
  }
}

TEST(CellGridGeometry, WindowOriginIsAnchorPlusMinTimesResolution) {
  const dog::CellGrid grid(0.25, 1.5, -2.25, std::nullopt, kNoLimit, defaults());
  const dog::MapWindow w = grid.window(box(-3, 2, 5, 7));
  EXPECT_EQ(w.resolution_m, 0.25);
  EXPECT_DOUBLE_EQ(w.origin_x_m, 1.5 - 3 * 0.25);
  EXPECT_DOUBLE_EQ(w.origin_y_m, -2.25 + 2 * 0.25);
  expectBoxEq(w.cells, box(-3, 2, 5, 7));
  EXPECT_EQ(w.cells.width(), 9);
  EXPECT_EQ(w.cells.height(), 6);
  const dog::MapWindow w2 = grid.window(box(-128, -64, -1, 63));
  EXPECT_DOUBLE_EQ(w2.origin_x_m, 1.5 - 32.0);
  EXPECT_DOUBLE_EQ(w2.origin_y_m, -2.25 - 16.0);
}

TEST(CellGridGeometry, NewGridIsEmptyAndWindowFollowsBounds) {
  dog::CellGrid grid(0.5, 10.0, 20.0, std::nullopt, kNoLimit, defaults());
  EXPECT_FALSE(grid.isFixed());
  EXPECT_TRUE(grid.bounds().empty());
  EXPECT_TRUE(grid.window().cells.empty());
  EXPECT_EQ(grid.allocatedTiles(), 0u);
  EXPECT_FALSE(grid.cell(0, 0).has_value());
  EXPECT_EQ(grid.findTile(0, 0), nullptr);

  writeCell(grid, -1, 70, 0.5f, 0, 0.0f, 0.1f, 0.1f);
  // Tile (-1, 1): cells [-64, -1] x [64, 127].
  expectBoxEq(grid.bounds(), box(-64, 64, -1, 127));
  const dog::MapWindow w = grid.window();
  expectBoxEq(w.cells, grid.bounds());
  EXPECT_DOUBLE_EQ(w.origin_x_m, 10.0 - 64 * 0.5);
  EXPECT_DOUBLE_EQ(w.origin_y_m, 20.0 + 64 * 0.5);
}

// =====================================================================================
// Cells: defaults, reading back
// =====================================================================================

TEST(CellGridCells, FreshTileCellsAreUnobservedWithDefaults) {
  dog::CellGrid grid(0.1, 0.0, 0.0, std::nullopt, kNoLimit, defaults());
  grid.reserve(box(5, 5, 5, 5));
  const dog::CellGrid::Tile* tile = grid.tileForWriting(5, 5);
  ASSERT_NE(tile, nullptr);
  EXPECT_EQ(grid.allocatedTiles(), 1u);
  for (int i = 0; i < dog::CellGrid::kTileCells; ++i) {
    ASSERT_EQ(tile->last_step[i], dog::kNeverObserved);
    ASSERT_EQ(tile->p_occ_given_free[i], 0.125f);
    ASSERT_EQ(tile->p_free_given_occ[i], 0.25f);
    ASSERT_EQ(tile->scan_record[i], 0u);
  }
  // Allocated but never observed: cell() reports nothing.
  EXPECT_FALSE(grid.cell(5, 5).has_value());
  EXPECT_FALSE(grid.cell(0, 0).has_value());
  // Same tile again: no new allocation.
  EXPECT_EQ(grid.tileForWriting(63, 63), tile);
  EXPECT_EQ(grid.allocatedTiles(), 1u);
}

TEST(CellGridCells, CellReadsBackWhatWasWritten) {
  dog::CellGrid grid(0.1, 0.0, 0.0, std::nullopt, kNoLimit, defaults());
  writeCell(grid, -7, 3, 0.75f, 12, -1.5f, 0.03f, 0.04f);
  const std::optional<dog::CellState> c = grid.cell(-7, 3);
  ASSERT_TRUE(c.has_value());
  EXPECT_EQ(c->p_occ, 0.75f);
  EXPECT_EQ(c->last_step, 12);
  EXPECT_EQ(c->log_odds, -1.5f);
  EXPECT_EQ(c->p_occ_given_free, 0.03f);
  EXPECT_EQ(c->p_free_given_occ, 0.04f);
  // Neighbours are untouched.
  EXPECT_FALSE(grid.cell(-6, 3).has_value());
  EXPECT_FALSE(grid.cell(-7, 4).has_value());
  EXPECT_FALSE(grid.cell(7, 3).has_value());
  EXPECT_FALSE(grid.cell(57, 3).has_value());  // x = -7 + 64: same offset, different tile
}

// =====================================================================================
// Growth
// =====================================================================================

TEST(CellGridGrowth, GrowsInWholeTilesAndKeepsCellsWhenGrowingNegative) {
  dog::CellGrid grid(0.05, 0.0, 0.0, std::nullopt, kNoLimit, defaults());
  dog::CellGrid::Tile* first = writeCell(grid, 5, 5, 0.8f, 3, 1.25f, 0.01f, 0.02f);
  ASSERT_NE(first, nullptr);
  expectBoxEq(grid.bounds(), box(0, 0, 63, 63));

  // Far in the negative direction: the index grows, cells and tiles never move.
  dog::CellGrid::Tile* far = writeCell(grid, -300, -700, 0.2f, 4, -0.5f, 0.03f, 0.04f);
  ASSERT_NE(far, nullptr);
  // floor(-300 / 64) = -5 -> x from -320; floor(-700 / 64) = -11 -> y from -704.
  expectBoxEq(grid.bounds(), box(-320, -704, 63, 63));
  EXPECT_EQ(grid.allocatedTiles(), 2u);
  EXPECT_EQ(grid.findTile(5, 5), first);
  EXPECT_EQ(grid.findTile(-300, -700), far);
  const std::optional<dog::CellState> c = grid.cell(5, 5);
  ASSERT_TRUE(c.has_value());
  EXPECT_EQ(c->p_occ, 0.8f);
  EXPECT_EQ(c->last_step, 3);
  EXPECT_EQ(c->log_odds, 1.25f);
  EXPECT_EQ(c->p_occ_given_free, 0.01f);
  EXPECT_EQ(c->p_free_given_occ, 0.02f);
  // Tiles in between the two are not allocated.
  EXPECT_EQ(grid.findTile(-100, -100), nullptr);
  EXPECT_FALSE(grid.cell(-100, -100).has_value());

  // And positive again, beyond the first tile.
  writeCell(grid, 1000, 130, 0.6f, 5, 0.0f, 0.0f, 0.0f);
  expectBoxEq(grid.bounds(), box(-320, -704, 1023, 191));
  EXPECT_EQ(grid.allocatedTiles(), 3u);
  EXPECT_EQ(grid.findTile(5, 5), first);
  EXPECT_EQ(grid.cell(5, 5)->p_occ, 0.8f);
  EXPECT_EQ(grid.cell(-300, -700)->p_occ, 0.2f);
}

TEST(CellGridGrowth, RandomWritesInAllDirectionsMatchAReferenceMap) {
  std::mt19937_64 rng(20240611);
  std::uniform_int_distribution<std::int32_t> coord(-2000, 2000);
  std::uniform_real_distribution<float> prob(0.0f, 1.0f);
  std::uniform_int_distribution<std::int32_t> stepd(0, 1000);
  dog::CellGrid grid(0.05, -1.0, 2.0, std::nullopt, kNoLimit, defaults());
  std::map<std::pair<std::int32_t, std::int32_t>, Stored> reference;
  std::map<std::pair<std::int32_t, std::int32_t>, const dog::CellGrid::Tile*> tile_of;
  dog::CellBox expected_bounds;
  for (int i = 0; i < 2000; ++i) {
    // Random walk mixed with jumps, so the index grows both gradually and by far.
    const std::int32_t x = coord(rng);
    const std::int32_t y = coord(rng);
    const Stored s{prob(rng), stepd(rng), prob(rng) * 4.0f - 2.0f, prob(rng), prob(rng)};
    dog::CellGrid::Tile* tile = writeCell(grid, x, y, s.p_occ, s.last_step, s.log_odds, s.p_of, s.p_fo);
    ASSERT_NE(tile, nullptr);
    reference[{x, y}] = s;
    const auto key = std::make_pair(floorDiv64(x), floorDiv64(y));
    const auto it = tile_of.find(key);
    if (it == tile_of.end()) {
      tile_of[key] = tile;
    } else {
      ASSERT_EQ(it->second, tile) << "a tile moved when the grid grew";
    }
    expected_bounds.include(64 * floorDiv64(x), 64 * floorDiv64(y));
    expected_bounds.include(64 * floorDiv64(x) + 63, 64 * floorDiv64(y) + 63);
  }
  EXPECT_EQ(grid.allocatedTiles(), tile_of.size());
  expectBoxEq(grid.bounds(), expected_bounds);
  for (const auto& [xy, s] : reference) {
    const std::optional<dog::CellState> c = grid.cell(xy.first, xy.second);
    ASSERT_TRUE(c.has_value()) << xy.first << ", " << xy.second;
    ASSERT_EQ(c->p_occ, s.p_occ);
    ASSERT_EQ(c->last_step, s.last_step);
    ASSERT_EQ(c->log_odds, s.log_odds);
    ASSERT_EQ(c->p_occ_given_free, s.p_of);
    ASSERT_EQ(c->p_free_given_occ, s.p_fo);
  }
  // Cells never written are unobserved (sampled).
  for (int i = 0; i < 2000; ++i) {
    const std::int32_t x = coord(rng);
    const std::int32_t y = coord(rng);
    if (reference.count({x, y}) != 0) continue;
    ASSERT_FALSE(grid.cell(x, y).has_value()) << x << ", " << y;
  }
}

TEST(CellGridGrowth, ReserveReturnsTheBoxAndMakesItWritable) {
  dog::CellGrid grid(0.05, 0.0, 0.0, std::nullopt, kNoLimit, defaults());
  const dog::CellBox wanted = box(-130, -10, 200, 70);
  expectBoxEq(grid.reserve(wanted), wanted);
  // Reserving allocates no tiles; writing anywhere inside the box works.
  EXPECT_EQ(grid.allocatedTiles(), 0u);
  EXPECT_TRUE(grid.bounds().empty());
  for (std::int32_t x : {-130, -65, -64, -1, 0, 63, 64, 200}) {
    for (std::int32_t y : {-10, -1, 0, 63, 64, 70}) {
      ASSERT_NE(grid.tileForWriting(x, y), nullptr) << x << ", " << y;
    }
  }
  // Tiles x in [-3, 3], y in [-1, 1].
  EXPECT_EQ(grid.allocatedTiles(), 6u * 3u);
  expectBoxEq(grid.bounds(), box(-192, -64, 255, 127));
  EXPECT_TRUE(grid.reserve(dog::CellBox{}).empty());
}

// =====================================================================================
// Limits: fixed bounds and the maximum size
// =====================================================================================

TEST(CellGridLimits, FixedBoundsNeverGrow) {
  const dog::CellBox fixed = box(0, 0, 99, 49);
  dog::CellGrid grid(0.1, -5.0, -2.5, fixed, 1000, defaults());
  EXPECT_TRUE(grid.isFixed());
  expectBoxEq(grid.bounds(), fixed);
  const dog::MapWindow w = grid.window();
  expectBoxEq(w.cells, fixed);
  EXPECT_DOUBLE_EQ(w.origin_x_m, -5.0);
  EXPECT_DOUBLE_EQ(w.origin_y_m, -2.5);

  // Reserving more is clipped to the fixed box.
  expectBoxEq(grid.reserve(box(-10, -10, 200, 200)), fixed);
  expectBoxEq(grid.reserve(box(50, 20, 300, 30)), box(50, 20, 99, 30));
  EXPECT_TRUE(grid.reserve(box(100, 0, 300, 30)).empty());
  EXPECT_TRUE(grid.reserve(box(-20, -20, -1, -1)).empty());
  expectBoxEq(grid.bounds(), fixed);

  for (const auto& xy : std::vector<std::pair<std::int32_t, std::int32_t>>{
           {-1, 0}, {0, -1}, {100, 0}, {0, 50}, {99, 50}, {100, 49}, {-64, -64}, {127, 63}}) {
    EXPECT_FALSE(grid.insideLimits(xy.first, xy.second)) << xy.first << ", " << xy.second;
    EXPECT_EQ(grid.tileForWriting(xy.first, xy.second), nullptr) << xy.first << ", " << xy.second;
    EXPECT_FALSE(grid.cell(xy.first, xy.second).has_value());
  }
  for (const auto& xy : std::vector<std::pair<std::int32_t, std::int32_t>>{
           {0, 0}, {99, 49}, {64, 0}, {0, 49}, {99, 0}}) {
    EXPECT_TRUE(grid.insideLimits(xy.first, xy.second)) << xy.first << ", " << xy.second;
    EXPECT_NE(grid.tileForWriting(xy.first, xy.second), nullptr) << xy.first << ", " << xy.second;
  }
  expectBoxEq(grid.bounds(), fixed);
  EXPECT_LE(grid.allocatedTiles(), 2u);  // the box spans tiles (0, 0) and (1, 0) only
}

TEST(CellGridLimits, GrowingGridStopsAtMaxCellsPerSide) {
  // 128 cells per side: x and y in [-64, 63].
  dog::CellGrid grid(0.25, 0.0, 0.0, std::nullopt, 128, defaults());
  expectBoxEq(grid.reserve(box(-1000, -70, 1000, 10)), box(-64, -64, 63, 10));
  EXPECT_TRUE(grid.reserve(box(64, 0, 1000, 10)).empty());
  for (const auto& xy : std::vector<std::pair<std::int32_t, std::int32_t>>{
           {64, 0}, {-65, 0}, {0, 64}, {0, -65}, {1000, 1000}}) {
    EXPECT_FALSE(grid.insideLimits(xy.first, xy.second));
    grid.reserve(box(xy.first, xy.second, xy.first, xy.second));
    EXPECT_EQ(grid.tileForWriting(xy.first, xy.second), nullptr) << xy.first << ", " << xy.second;
  }
  for (const auto& xy : std::vector<std::pair<std::int32_t, std::int32_t>>{
           {63, 63}, {-64, -64}, {63, -64}, {-64, 63}}) {
    EXPECT_TRUE(grid.insideLimits(xy.first, xy.second));
    grid.reserve(box(xy.first, xy.second, xy.first, xy.second));
    EXPECT_NE(grid.tileForWriting(xy.first, xy.second), nullptr) << xy.first << ", " << xy.second;
  }
  expectBoxEq(grid.bounds(), box(-64, -64, 63, 63));
  EXPECT_EQ(grid.allocatedTiles(), 4u);
}

TEST(CellGridLimits, ConstructorRejectsBadArguments) {
  EXPECT_THROW(dog::CellGrid(0.0, 0.0, 0.0, std::nullopt, 128, defaults()), std::invalid_argument);
  EXPECT_THROW(dog::CellGrid(-0.1, 0.0, 0.0, std::nullopt, 128, defaults()), std::invalid_argument);
  EXPECT_THROW(dog::CellGrid(std::nan(""), 0.0, 0.0, std::nullopt, 128, defaults()),
               std::invalid_argument);
  EXPECT_THROW(dog::CellGrid(std::numeric_limits<double>::infinity(), 0.0, 0.0, std::nullopt, 128,
                             defaults()),
               std::invalid_argument);
  EXPECT_THROW(dog::CellGrid(0.1, std::nan(""), 0.0, std::nullopt, 128, defaults()),
               std::invalid_argument);
  EXPECT_THROW(dog::CellGrid(0.1, 0.0, std::numeric_limits<double>::infinity(), std::nullopt, 128,
                             defaults()),
               std::invalid_argument);
  EXPECT_THROW(dog::CellGrid(0.1, 0.0, 0.0, std::nullopt, 63, defaults()), std::invalid_argument);
  EXPECT_THROW(dog::CellGrid(0.1, 0.0, 0.0, dog::CellBox{}, 128, defaults()), std::invalid_argument);
  EXPECT_THROW(dog::CellGrid(0.1, 0.0, 0.0, box(0, 0, 128, 10), 128, defaults()),
               std::invalid_argument);
  EXPECT_NO_THROW(dog::CellGrid(0.1, 0.0, 0.0, box(0, 0, 127, 127), 128, defaults()));
}

TEST(CellGridMemory, BytesPerCellIsSmall) {
  // 72 bytes of cell state plus the tile's coordinates shared by its 4096 cells; the budget
  // moved from 64 to 80 bytes with the learning issue: the last step's evidence (2 bytes)
  // that online sensor-model learning weighs once the next step is seen, and the joint
  // posterior over five kinds of cells (10 floats where each cell's online EM keeps 8).
  static_assert(dog::CellGrid::bytesPerCell() <= 80.0, "a cell must take at most 80 bytes");
  EXPECT_LE(dog::CellGrid::bytesPerCell(), 72.01);
  EXPECT_DOUBLE_EQ(dog::CellGrid::bytesPerCell(),
                   static_cast<double>(sizeof(dog::CellGrid::Tile)) / (64.0 * 64.0));
  EXPECT_EQ(dog::CellGrid::kTileSize, 64);
  EXPECT_EQ(dog::CellGrid::kTileCells, 64 * 64);
}

// =====================================================================================
// Row-major layout of evaluated layers (row = y)
// =====================================================================================

TEST(CellGridLayout, EvaluateLayerIsRowMajorWithRowEqualToY) {
  dog::CellGrid grid(0.1, 0.0, 0.0, std::nullopt, kNoLimit, defaults());
  // A distinct log-odds value per cell over a box straddling four tiles.
  const dog::CellBox b = box(-3, -2, 4, 1);  // 8 wide, 4 high
  std::map<std::pair<std::int32_t, std::int32_t>, float> p_of_value;
  for (std::int32_t y = b.min_y; y <= b.max_y; ++y) {
    for (std::int32_t x = b.min_x; x <= b.max_x; ++x) {
      if ((x + y) % 3 == 0) continue;  // leave some cells unobserved
      const float v = static_cast<float>(x * 100 + y) / 1024.0f + 0.5f;
      writeCell(grid, x, y, 0.5f, 0, 0.0f, v, 0.0f);
      p_of_value[{x, y}] = v;
    }
  }
  std::vector<float> values;
  dog::evaluateLayer(grid, dog::Layer::kOccGivenFree, 0, 0, b, &values);
  ASSERT_EQ(values.size(), 32u);
  for (std::int32_t y = b.min_y; y <= b.max_y; ++y) {
    for (std::int32_t x = b.min_x; x <= b.max_x; ++x) {
      const std::size_t index = static_cast<std::size_t>((y - b.min_y) * 8 + (x - b.min_x));
      const auto it = p_of_value.find({x, y});
      if (it == p_of_value.end()) {
        EXPECT_TRUE(std::isnan(values[index])) << x << ", " << y;
      } else {
        EXPECT_EQ(values[index], it->second) << x << ", " << y;
      }
    }
  }
  // Hand-picked entries: index 0 = (min_x, min_y) = (-3, -2); index 7 = (4, -2);
  // index 8 = (-3, -1); last = (4, 1).
  EXPECT_EQ(values[0], p_of_value.at({-3, -2}));
  EXPECT_EQ(values[7], p_of_value.at({4, -2}));
  EXPECT_EQ(values[8], p_of_value.at({-3, -1}));
  EXPECT_EQ(values[31], p_of_value.at({4, 1}));
}

TEST(CellGridLayout, EvaluateLayerOverBoundsOfLimitedGridSeesEveryObservedCell) {
  // max_cells_per_side = 100: limits [-50, 49]; the allocated tiles (whole tiles) reach past
  // them, so bounds() starts at -64. Every observed cell must still be evaluated.
  dog::CellGrid grid(0.1, 0.0, 0.0, std::nullopt, 100, defaults());
  ASSERT_NE(writeCell(grid, -10, -20, 0.5f, 0, 0.0f, 0.375f, 0.0f), nullptr);
  ASSERT_NE(writeCell(grid, 40, 30, 0.5f, 0, 0.0f, 0.625f, 0.0f), nullptr);
  ASSERT_TRUE(grid.cell(-10, -20).has_value());
  const dog::CellBox b = grid.bounds();
  std::vector<float> values;
  dog::evaluateLayer(grid, dog::Layer::kOccGivenFree, 0, 0, b, &values);
  ASSERT_EQ(values.size(), static_cast<std::size_t>(b.width() * b.height()));
  const auto at = [&](std::int32_t x, std::int32_t y) {
    return values[static_cast<std::size_t>((y - b.min_y) * b.width() + (x - b.min_x))];
  };
  EXPECT_EQ(at(-10, -20), 0.375f) << "observed cell (-10, -20) evaluated as NaN over bounds() "
                                  << "[" << b.min_x << ", " << b.max_x << "]";
  EXPECT_EQ(at(40, 30), 0.625f);
}

TEST(CellGridLayout, EvaluateLayerOverLargerBoxThanUnalignedFixedBounds) {
  // Fixed box [10, 20]^2 (not on tile edges); evaluate over a larger box [0, 30]^2.
  dog::CellGrid grid(0.1, 0.0, 0.0, box(10, 10, 20, 20), 1000, defaults());
  ASSERT_NE(writeCell(grid, 15, 15, 0.5f, 0, 0.0f, 0.375f, 0.0f), nullptr);
  std::vector<float> values;
  dog::evaluateLayer(grid, dog::Layer::kOccGivenFree, 0, 0, box(0, 0, 30, 30), &values);
  ASSERT_EQ(values.size(), 31u * 31u);
  EXPECT_EQ(values[15 * 31 + 15], 0.375f) << "observed cell (15, 15) evaluated as NaN";
  // Over exactly the fixed box it is found.
  dog::evaluateLayer(grid, dog::Layer::kOccGivenFree, 0, 0, grid.bounds(), &values);
  ASSERT_EQ(values.size(), 11u * 11u);
  EXPECT_EQ(values[5 * 11 + 5], 0.375f);
}

// =====================================================================================
// The grid as the mapper configures it: origin, fixed bounds, size limit
// =====================================================================================

namespace {

dog::Scan oneBeam(double stamp, double x, double y, double yaw, float range, double range_max) {
  dog::Scan scan;
  scan.stamp_s = stamp;
  scan.laser_pose.x_m = x;
  scan.laser_pose.y_m = y;
  scan.laser_pose.yaw_rad = yaw;
  scan.angle_min_rad = 0.0;
  scan.angle_increment_rad = 0.01;
  scan.range_min_m = 0.0;
  scan.range_max_m = range_max;
  scan.ranges_m = {range};
  return scan;
}

dog::MapperConfig quarterMetreConfig() {
  dog::MapperConfig config;
  config.resolution_m = 0.25;
  config.time_step_s = 1.0;
  config.prior_transitions = dog::TransitionParams{0.0, 0.0};
  config.static_clamp = dog::LogOddsClamp{-100.0, 100.0};
  return config;
}

std::vector<std::pair<std::int32_t, std::int32_t>> observedCells(const dog::CellGrid& grid) {
  std::vector<std::pair<std::int32_t, std::int32_t>> cells;
  const dog::CellBox b = grid.bounds();
  if (b.empty()) return cells;
  for (std::int32_t y = b.min_y; y <= b.max_y; ++y) {
    for (std::int32_t x = b.min_x; x <= b.max_x; ++x) {
      if (grid.cell(x, y)) cells.emplace_back(x, y);
    }
  }
  return cells;
}

}  // namespace

TEST(MapperGrid, OriginPlacesCellZeroAndFloorsNegativeCoordinates) {
  dog::MapperConfig config = quarterMetreConfig();
  config.origin_x_m = 1.0;
  config.origin_y_m = -2.0;
  dog::Mapper mapper(config);
  // Laser at world (0.875, -2.125) = lattice (-0.5, -0.5): cell (-1, -1). Beam along -x,
  // range 0.5 m = 2 cells: end at lattice (-2.5, -0.5) -> cells (-1,-1), (-2,-1) missed,
  // (-3, -1) hit.
  const dog::ScanResult r = mapper.integrate(oneBeam(0.0, 0.875, -2.125, kPi, 0.5f, 10.0));
  ASSERT_EQ(r.status, dog::ScanStatus::kIntegrated);
  mapper.finishStep();
  const auto cells = observedCells(mapper.grid());
  const std::vector<std::pair<std::int32_t, std::int32_t>> expected{{-3, -1}, {-2, -1}, {-1, -1}};
  EXPECT_EQ(cells, expected);
  // Hit cell has positive log-odds, missed ones negative.
  EXPECT_GT(mapper.grid().cell(-3, -1)->log_odds, 0.0f);
  EXPECT_LT(mapper.grid().cell(-2, -1)->log_odds, 0.0f);
  EXPECT_LT(mapper.grid().cell(-1, -1)->log_odds, 0.0f);
  // Whole tile (-1, -1); window origin = origin + min * resolution.
  expectBoxEq(mapper.grid().bounds(), box(-64, -64, -1, -1));
  const dog::MapWindow w = mapper.grid().window();
  EXPECT_DOUBLE_EQ(w.origin_x_m, 1.0 - 64 * 0.25);
  EXPECT_DOUBLE_EQ(w.origin_y_m, -2.0 - 64 * 0.25);
  EXPECT_EQ(w.resolution_m, 0.25);
}

TEST(MapperGrid, GrowingNegativeKeepsEarlierCells) {
  dog::Mapper mapper(quarterMetreConfig());
  // Step 0: laser at cell (0, 0) centre, beam +x range 1 m -> (0..3, 0) missed, (4, 0) hit.
  ASSERT_EQ(mapper.integrate(oneBeam(0.0, 0.125, 0.125, 0.0, 1.0f, 10.0)).status,
            dog::ScanStatus::kIntegrated);
  // Step 1: far away in the negative quadrant: laser at cell (-400, -300) centre.
  ASSERT_EQ(mapper.integrate(oneBeam(1.0, -99.875, -74.875, 0.0, 1.0f, 10.0)).status,
            dog::ScanStatus::kIntegrated);
  mapper.finishStep();
  const auto before_hit = mapper.grid().cell(4, 0);
  ASSERT_TRUE(before_hit.has_value());
  EXPECT_EQ(before_hit->last_step, 0);
  EXPECT_GT(before_hit->log_odds, 0.0f);
  for (std::int32_t x = 0; x < 4; ++x) {
    ASSERT_TRUE(mapper.grid().cell(x, 0).has_value());
    EXPECT_LT(mapper.grid().cell(x, 0)->log_odds, 0.0f);
    EXPECT_EQ(mapper.grid().cell(x, 0)->last_step, 0);
  }
  ASSERT_TRUE(mapper.grid().cell(-396, -300).has_value());
  EXPECT_EQ(mapper.grid().cell(-396, -300)->last_step, 1);
  // Tiles: x floor(-400/64) = -7 -> -448, y floor(-300/64) = -5 -> -320.
  expectBoxEq(mapper.grid().bounds(), box(-448, -320, 63, 63));
  EXPECT_EQ(mapper.grid().allocatedTiles(), 2u);
  EXPECT_EQ(observedCells(mapper.grid()).size(), 10u);
}

TEST(MapperGrid, FixedBoundsDropCellsOutsideAndNeverGrow) {
  dog::MapperConfig config = quarterMetreConfig();
  config.fixed_bounds = true;
  config.width_m = 1.0;   // 4 cells
  config.height_m = 0.5;  // 2 cells
  dog::Mapper mapper(config);
  expectBoxEq(mapper.grid().bounds(), box(0, 0, 3, 1));
  // Beam +x from cell (0, 0) centre, range 2 m -> lattice end 8.5: cells 0..8 of row 0;
  // 0..3 inside (missed), 4..7 and the hit cell 8 outside (5 cells dropped).
  const dog::ScanResult r = mapper.integrate(oneBeam(0.0, 0.125, 0.125, 0.0, 2.0f, 10.0));
  ASSERT_EQ(r.status, dog::ScanStatus::kIntegrated);
  EXPECT_EQ(r.beams_hit, 1u);
  EXPECT_EQ(r.cells_outside, 5u);
  // Beam -y from the same cell, range 1 m: cells (0, 0), (0, -1..-3) missed, (0, -4) hit;
  // 4 outside.
  const dog::ScanResult r2 = mapper.integrate(oneBeam(0.5, 0.125, 0.125, -kPi / 2, 1.0f, 10.0));
  EXPECT_EQ(r2.cells_outside, 4u);
  // A laser outside the box entirely: everything is outside (4 cells: 3 missed, 1 hit).
  const dog::ScanResult r3 = mapper.integrate(oneBeam(0.7, -5.125, 0.125, 0.0, 0.75f, 10.0));
  EXPECT_EQ(r3.status, dog::ScanStatus::kIntegrated);
  EXPECT_EQ(r3.cells_outside, 4u);
  mapper.finishStep();
  expectBoxEq(mapper.grid().bounds(), box(0, 0, 3, 1));
  // Only cells inside the box changed (the tile holding the box is larger than it).
  expectBoxEq(mapper.takeChangedCells(), box(0, 0, 3, 0));
  const dog::CellGrid::Tile* tile = mapper.grid().findTile(0, 0);
  ASSERT_NE(tile, nullptr);
  for (std::int32_t x = 4; x <= 8; ++x) {
    EXPECT_EQ(tile->last_step[dog::CellGrid::offsetOf(x, 0)], dog::kNeverObserved)
        << "cell (" << x << ", 0) outside the fixed bounds was written";
  }
  const auto cells = observedCells(mapper.grid());
  const std::vector<std::pair<std::int32_t, std::int32_t>> expected{{0, 0}, {1, 0}, {2, 0}, {3, 0}};
  EXPECT_EQ(cells, expected);
  for (const auto& xy : cells) EXPECT_LT(mapper.grid().cell(xy.first, xy.second)->log_odds, 0.0f);
  EXPECT_FALSE(mapper.grid().cell(8, 0).has_value());
  EXPECT_FALSE(mapper.grid().cell(0, -4).has_value());
  EXPECT_EQ(mapper.grid().window().cells.width(), 4);
  EXPECT_EQ(mapper.grid().window().cells.height(), 2);
}

TEST(MapperGrid, FixedBoundsCellCountIsTheSizeOverResolution) {
  // [origin, origin + size) holds size / resolution cells, also where the quotient is not
  // exact in floating point (2.1 / 0.3 = 7.000000000000001, 1.11 / 0.01 = 111.00000000000001).
  struct Case {
    double resolution;
    double size;
    std::int64_t cells;
  };
  for (const Case& c : {Case{0.25, 1.0, 4}, Case{0.1, 1.1, 11}, Case{0.05, 2.5, 50},
                        Case{0.3, 2.1, 7}, Case{0.01, 1.11, 111}}) {
    dog::MapperConfig config;
    config.resolution_m = c.resolution;
    config.fixed_bounds = true;
    config.width_m = c.size;
    config.height_m = c.size;
    const dog::Mapper mapper(config);
    EXPECT_EQ(mapper.grid().bounds().width(), c.cells)
        << "resolution " << c.resolution << " width " << c.size;
    EXPECT_EQ(mapper.grid().bounds().height(), c.cells)
        << "resolution " << c.resolution << " height " << c.size;
  }
}

TEST(MapperGrid, MaxMapSizeLimitsGrowth) {
  dog::MapperConfig config = quarterMetreConfig();
  config.max_map_size_m = 32.0;  // 128 cells: x, y in [-64, 63]
  config.max_free_range_m = 100.0;
  dog::Mapper mapper(config);
  // +x, range 20 m = 80 cells: lattice end 80.5; cells 64..80 (17, incl. the hit) outside.
  const dog::ScanResult r = mapper.integrate(oneBeam(0.0, 0.125, 0.125, 0.0, 20.0f, 50.0));
  EXPECT_EQ(r.status, dog::ScanStatus::kIntegrated);
  EXPECT_EQ(r.cells_outside, 17u);
  // -x, range 20 m: lattice end -79.5; cells -65..-80 (16) outside.
  const dog::ScanResult r2 = mapper.integrate(oneBeam(0.5, 0.125, 0.125, kPi, 20.0f, 50.0));
  EXPECT_EQ(r2.cells_outside, 16u);
  mapper.finishStep();
  expectBoxEq(mapper.grid().bounds(), box(-64, 0, 63, 63));
  EXPECT_TRUE(mapper.grid().cell(63, 0).has_value());
  EXPECT_TRUE(mapper.grid().cell(-64, 0).has_value());
  EXPECT_LT(mapper.grid().cell(63, 0)->log_odds, 0.0f);  // missed, the hit was outside
  EXPECT_EQ(observedCells(mapper.grid()).size(), 128u);
}
