// Tests for core::traverseSegment (include/dynamic_occupancy_grid/core/grid/traversal.h).
//
// Contract under test: for the closed segment P(t) = P0 + t * (P1 - P0), t in [0, 1], the
// cells visited (visitor calls, then the returned end cell) are exactly the set
//   { (floor(x(t)), floor(y(t))) : t in [0, 1] }
// with cells as half-open squares [ix, ix + 1) x [iy, iy + 1), each cell once, in the order
// in which the segment first reaches it.
//
// The main check compares against an independent, exact reference: endpoints are restricted
// to a dyadic lattice (coordinate = integer / 2^k), so they are exact doubles and the
// reference can work entirely in integers (rational crossing parameters, integer floor
// division). Many batches are built to hit the tricky situations often: rays along grid
// lines, rays through lattice corners in all four diagonal directions, endpoints on cell
// boundaries or corners, negative directions, zero-length, very short and very long rays.
// For arbitrary (non-dyadic) doubles only structural properties are checked, since the
// header allows near-corner crossings to be ordered either way under rounding.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/traversal.h"

namespace {

using dynamic_occupancy_grid::core::CellXY;
using dynamic_occupancy_grid::core::traverseSegment;

// 128-bit integers keep every product in the reference exact with a wide margin
// (__extension__ keeps -Wpedantic quiet about the GCC/Clang builtin type).
__extension__ typedef __int128 Int128;

// Default lattice: coordinates are multiples of 1/256 cell.
constexpr std::int64_t kScale = 256;

// ---------------------------------------------------------------------------------------
// Helpers shared by all tests
// ---------------------------------------------------------------------------------------

// Full sequence produced by the implementation: every visited cell, then the returned end
// cell (the caller treats it separately, but it is part of the segment's cell set).
std::vector<CellXY> runTraversal(double u0, double v0, double u1, double v1) {
  std::vector<CellXY> cells;
  const CellXY end = traverseSegment(
      u0, v0, u1, v1, [&cells](std::int32_t x, std::int32_t y) { cells.push_back(CellXY{x, y}); });
  cells.push_back(end);
  return cells;
}

std::string toString(const std::vector<CellXY>& cells) {
  std::ostringstream out;
  out << "[";
  for (std::size_t i = 0; i < cells.size(); ++i) {
    out << (i == 0 ? "" : " ") << "(" << cells[i].x << "," << cells[i].y << ")";
  }
  out << "] (" << cells.size() << " cells)";
  return out.str();
}

std::string segmentString(double u0, double v0, double u1, double v1) {
  std::ostringstream out;
  out.precision(17);
  out << "(" << u0 << ", " << v0 << ") -> (" << u1 << ", " << v1 << ")";
  return out.str();
}

// ---------------------------------------------------------------------------------------
// Exact reference on a dyadic lattice
// ---------------------------------------------------------------------------------------

// Endpoints in lattice units: the real coordinate is value / scale (scale a power of two,
// so value / scale is an exact double for the magnitudes used here).
struct LatticeSegment {
  std::int64_t x0, y0, x1, y1;
};

// Rational number num / den with den > 0.
struct Rational {
  Int128 num;
  Int128 den;
};

bool rationalLess(const Rational& a, const Rational& b) { return a.num * b.den < b.num * a.den; }
bool rationalEqual(const Rational& a, const Rational& b) { return a.num * b.den == b.num * a.den; }

// Floor of a / b for b > 0 (C++ division truncates towards zero).
Int128 floorDiv(Int128 a, Int128 b) {
  Int128 q = a / b;
  if (a % b != 0 && a < 0) --q;
  return q;
}
Int128 ceilDiv(Int128 a, Int128 b) { return -floorDiv(-a, b); }

// Adds every t in [0, 1] at which the coordinate c(t) = c0 + t (c1 - c0) equals a cell
// boundary k * scale. Only these parameters (and t = 0, 1) can change floor(P(t)).
void addBoundaryCrossings(std::int64_t c0, std::int64_t c1, std::int64_t scale,
                          std::vector<Rational>* ts) {
  if (c0 == c1) return;  // No motion along this axis: the cell index never changes.
  const Int128 lo = std::min(c0, c1);
  const Int128 hi = std::max(c0, c1);
  for (Int128 k = ceilDiv(lo, scale); k <= floorDiv(hi, scale); ++k) {
    Rational t{k * scale - c0, static_cast<Int128>(c1) - c0};
    if (t.den < 0) {
      t.num = -t.num;
      t.den = -t.den;
    }
    ts->push_back(t);
  }
}

// Cell holding P(t), computed exactly: floor((c0 + t (c1 - c0)) / scale).
CellXY cellAt(const LatticeSegment& s, std::int64_t scale, const Rational& t) {
  const Int128 x_num = static_cast<Int128>(s.x0) * t.den + static_cast<Int128>(s.x1 - s.x0) * t.num;
  const Int128 y_num = static_cast<Int128>(s.y0) * t.den + static_cast<Int128>(s.y1 - s.y0) * t.num;
  return CellXY{static_cast<std::int32_t>(floorDiv(x_num, t.den * scale)),
                static_cast<std::int32_t>(floorDiv(y_num, t.den * scale))};
}

// Expected ordered cell sequence: floor(P(t)) is constant on each open interval between
// consecutive critical parameters, so sampling every critical t and every interval
// midpoint, in increasing t, enumerates all cells in order of first appearance.
std::vector<CellXY> referenceCells(const LatticeSegment& s, std::int64_t scale) {
  std::vector<Rational> ts{{0, 1}, {1, 1}};
  addBoundaryCrossings(s.x0, s.x1, scale, &ts);
  addBoundaryCrossings(s.y0, s.y1, scale, &ts);
  std::sort(ts.begin(), ts.end(), rationalLess);
  ts.erase(std::unique(ts.begin(), ts.end(), rationalEqual), ts.end());

  std::vector<CellXY> samples;
  for (std::size_t i = 0; i < ts.size(); ++i) {
    samples.push_back(cellAt(s, scale, ts[i]));
    if (i + 1 < ts.size()) {
      const Rational& a = ts[i];
      const Rational& b = ts[i + 1];
      const Rational mid{a.num * b.den + b.num * a.den, 2 * a.den * b.den};
      samples.push_back(cellAt(s, scale, mid));
    }
  }
  std::vector<CellXY> cells;
  for (const CellXY& c : samples) {
    if (cells.empty() || cells.back() != c) cells.push_back(c);
  }
  return cells;
}

// Compares the implementation with the exact reference for one lattice segment.
::testing::AssertionResult matchesReference(const LatticeSegment& s, std::int64_t scale) {
  const double d = static_cast<double>(scale);
  const double u0 = static_cast<double>(s.x0) / d;
  const double v0 = static_cast<double>(s.y0) / d;
  const double u1 = static_cast<double>(s.x1) / d;
  const double v1 = static_cast<double>(s.y1) / d;
  const std::vector<CellXY> expected = referenceCells(s, scale);

  // Sanity of the reference itself: a straight segment never re-enters a cell.
  std::set<std::pair<std::int32_t, std::int32_t>> seen;
  for (const CellXY& c : expected) {
    if (!seen.insert({c.x, c.y}).second) {
      return ::testing::AssertionFailure() << "reference repeats a cell for " << segmentString(u0, v0, u1, v1)
                                           << ": " << toString(expected);
    }
  }

  const std::vector<CellXY> actual = runTraversal(u0, v0, u1, v1);
  if (actual == expected) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << "segment " << segmentString(u0, v0, u1, v1) << " (lattice "
                                       << s.x0 << "," << s.y0 << " -> " << s.x1 << "," << s.y1 << " / " << scale
                                       << ")\n  expected " << toString(expected) << "\n  actual   "
                                       << toString(actual);
}

// Runs a batch against the reference; reports at most a few failures so one bug does not
// flood the output, but always reports how many segments failed in total.
void checkBatch(const std::vector<LatticeSegment>& batch, std::int64_t scale) {
  int failures = 0;
  for (const LatticeSegment& s : batch) {
    const ::testing::AssertionResult r = matchesReference(s, scale);
    if (!r) {
      if (failures < 8) ADD_FAILURE() << r.message();
      ++failures;
    }
  }
  EXPECT_EQ(failures, 0) << "of " << batch.size() << " segments";
}

// Deterministic random source shared by the batch generators.
class Rng {
 public:
  explicit Rng(std::uint64_t seed) : engine_(seed) {}
  std::int64_t uniform(std::int64_t lo, std::int64_t hi) {
    return std::uniform_int_distribution<std::int64_t>(lo, hi)(engine_);
  }
  int sign() { return uniform(0, 1) == 0 ? -1 : 1; }
  bool chance(int one_in) { return uniform(0, one_in - 1) == 0; }
  std::mt19937_64& engine() { return engine_; }

 private:
  std::mt19937_64 engine_;
};

// A lattice coordinate in [-cells, cells] cells; when on_line, exactly on a cell boundary.
std::int64_t coord(Rng& rng, std::int64_t cells, bool on_line = false) {
  return on_line ? rng.uniform(-cells, cells) * kScale : rng.uniform(-cells * kScale, cells * kScale);
}

// ---------------------------------------------------------------------------------------
// 3. Hand-written cases with the expected sequence spelled out
// ---------------------------------------------------------------------------------------

struct HandCase {
  double u0, v0, u1, v1;
  std::vector<CellXY> expected;
};

TEST(TraverseSegment, HandWrittenCases) {
  const std::vector<HandCase> cases = {
      // Plain horizontal and vertical rays through cell interiors, both directions.
      {0.5, 0.5, 2.5, 0.5, {{0, 0}, {1, 0}, {2, 0}}},
      {2.5, 0.5, 0.5, 0.5, {{2, 0}, {1, 0}, {0, 0}}},
      {0.5, 0.5, 0.5, 2.5, {{0, 0}, {0, 1}, {0, 2}}},
      {0.5, 2.5, 0.5, 0.5, {{0, 2}, {0, 1}, {0, 0}}},
      // Along the grid line y = 1: only row 1 (the line belongs to the cells above it).
      {0.5, 1.0, 2.5, 1.0, {{0, 1}, {1, 1}, {2, 1}}},
      {2.5, 1.0, 0.5, 1.0, {{2, 1}, {1, 1}, {0, 1}}},
      // Along the grid line x = 1: only column 1, both directions.
      {1.0, 0.5, 1.0, 2.5, {{1, 0}, {1, 1}, {1, 2}}},
      {1.0, 2.5, 1.0, 0.5, {{1, 2}, {1, 1}, {1, 0}}},
      // Along a grid line from corner to corner, both directions.
      {0.0, 0.0, 2.0, 0.0, {{0, 0}, {1, 0}, {2, 0}}},
      {2.0, 0.0, 0.0, 0.0, {{2, 0}, {1, 0}, {0, 0}}},
      {0.0, -2.0, 0.0, 0.0, {{0, -2}, {0, -1}, {0, 0}}},
      // Through the corner (1, 1) with both coordinates growing / shrinking: one diagonal step.
      {0.5, 0.5, 1.5, 1.5, {{0, 0}, {1, 1}}},
      {1.5, 1.5, 0.5, 0.5, {{1, 1}, {0, 0}}},
      // Through the corner (1, 1) with mixed directions: the corner point itself lies in the
      // cell reached by the growing coordinate, which is visited in between.
      {1.5, 0.5, 0.5, 1.5, {{1, 0}, {1, 1}, {0, 1}}},  // -x, +y
      {0.5, 1.5, 1.5, 0.5, {{0, 1}, {1, 1}, {1, 0}}},  // +x, -y
      // Corner-to-corner diagonals in all four directions.
      {0.0, 0.0, 2.0, 2.0, {{0, 0}, {1, 1}, {2, 2}}},
      {2.0, 2.0, 0.0, 0.0, {{2, 2}, {1, 1}, {0, 0}}},
      {0.0, 2.0, 2.0, 0.0, {{0, 2}, {0, 1}, {1, 1}, {1, 0}, {2, 0}}},
      {2.0, 0.0, 0.0, 2.0, {{2, 0}, {1, 0}, {1, 1}, {0, 1}, {0, 2}}},
      // Through the origin corner with negative coordinates.
      {-0.5, -0.5, 0.5, 0.5, {{-1, -1}, {0, 0}}},
      {0.5, 0.5, -0.5, -0.5, {{0, 0}, {-1, -1}}},
      {-0.5, 0.5, 0.5, -0.5, {{-1, 0}, {0, 0}, {0, -1}}},
      // A corner in the middle of a shallow ray: x crosses 1 at t = 1/6, then x = 2 and
      // y = 1 together at t = 1/2 (diagonal step), then x = 3 at t = 5/6.
      {0.5, 0.5, 3.5, 1.5, {{0, 0}, {1, 0}, {2, 1}, {3, 1}}},
      // Start on a boundary moving in the negative direction: the start point is still in
      // cell 1, the step to cell 0 happens right after it.
      {1.0, 0.5, 0.5, 0.5, {{1, 0}, {0, 0}}},
      {0.5, 1.0, 0.5, 0.5, {{0, 1}, {0, 0}}},
      // Start on a corner moving -x,+y / +x,-y.
      {1.0, 1.0, 0.5, 1.5, {{1, 1}, {0, 1}}},
      {1.0, 1.0, 1.5, 0.5, {{1, 1}, {1, 0}}},
      {1.0, 1.0, 0.5, 0.5, {{1, 1}, {0, 0}}},
      // End on a boundary: moving down the end point still belongs to the upper cell only;
      // moving up the end point already belongs to the next cell.
      {1.5, 0.5, 1.0, 0.5, {{1, 0}}},
      {0.5, 0.5, 1.0, 0.5, {{0, 0}, {1, 0}}},
      {1.5, 1.5, 1.0, 1.0, {{1, 1}}},
      {0.5, 0.5, 1.0, 1.0, {{0, 0}, {1, 1}}},
      // End on a corner with mixed directions.
      {0.5, 1.5, 1.0, 1.0, {{0, 1}, {1, 1}}},
      {1.5, 0.5, 1.0, 1.0, {{1, 0}, {1, 1}}},
      // Inside one cell, and zero-length segments (the visitor is never called).
      {0.2, 0.3, 0.8, 0.9, {{0, 0}}},
      {0.3, 0.7, 0.3, 0.7, {{0, 0}}},
      {1.0, 1.0, 1.0, 1.0, {{1, 1}}},
      {-0.5, -0.5, -0.5, -0.5, {{-1, -1}}},
      {-3.0, 2.0, -3.0, 2.0, {{-3, 2}}},
  };
  for (const HandCase& c : cases) {
    const std::vector<CellXY> actual = runTraversal(c.u0, c.v0, c.u1, c.v1);
    EXPECT_TRUE(actual == c.expected) << "segment " << segmentString(c.u0, c.v0, c.u1, c.v1) << "\n  expected "
                                      << toString(c.expected) << "\n  actual   " << toString(actual);
  }
}

// The end cell is returned, never passed to the visitor; a zero-length segment visits nothing.
TEST(TraverseSegment, EndCellIsReturnedNotVisited) {
  int calls = 0;
  const CellXY end = traverseSegment(0.5, 0.5, 0.5, 0.5, [&calls](std::int32_t, std::int32_t) { ++calls; });
  EXPECT_EQ(calls, 0);
  EXPECT_EQ(end.x, 0);
  EXPECT_EQ(end.y, 0);

  std::vector<CellXY> visited;
  const CellXY end2 = traverseSegment(
      0.5, 0.5, 3.5, 0.5, [&visited](std::int32_t x, std::int32_t y) { visited.push_back(CellXY{x, y}); });
  EXPECT_TRUE((visited == std::vector<CellXY>{{0, 0}, {1, 0}, {2, 0}})) << toString(visited);
  EXPECT_EQ(end2.x, 3);
  EXPECT_EQ(end2.y, 0);
}

// The reference is checked against the hand-written expectations too, so a bug shared by
// reference and implementation cannot hide (values are multiples of 1/2, hence on-lattice).
TEST(TraverseSegment, ReferenceAgreesWithHandWrittenCases) {
  const LatticeSegment a{128, 384, 384, 128};  // (0.5,1.5) -> (1.5,0.5)
  EXPECT_TRUE((referenceCells(a, kScale) == std::vector<CellXY>{{0, 1}, {1, 1}, {1, 0}}))
      << toString(referenceCells(a, kScale));
  const LatticeSegment b{512, 0, 0, 512};  // (2,0) -> (0,2)
  EXPECT_TRUE((referenceCells(b, kScale) == std::vector<CellXY>{{2, 0}, {1, 0}, {1, 1}, {0, 1}, {0, 2}}))
      << toString(referenceCells(b, kScale));
  const LatticeSegment c{640, 256, 128, 256};  // (2.5,1) -> (0.5,1)
  EXPECT_TRUE((referenceCells(c, kScale) == std::vector<CellXY>{{2, 1}, {1, 1}, {0, 1}}))
      << toString(referenceCells(c, kScale));
}

// ---------------------------------------------------------------------------------------
// 1 + 2. Exact comparison with the reference over random and edge-case batches
// ---------------------------------------------------------------------------------------

// Generic random rays on the 1/256 lattice within [-40, 40] cells.
TEST(TraverseSegmentExact, RandomRays) {
  Rng rng(0x5eed0001);
  std::vector<LatticeSegment> batch;
  for (int i = 0; i < 5000; ++i) batch.push_back({coord(rng, 40), coord(rng, 40), coord(rng, 40), coord(rng, 40)});
  checkBatch(batch, kScale);
}

// Coarse sub-lattices (integers, halves, quarters, eighths) in a small window: endpoints
// land on lines and corners and rays pass through corners very often.
TEST(TraverseSegmentExact, CoarseLatticeRays) {
  Rng rng(0x5eed0002);
  std::vector<LatticeSegment> batch;
  const std::int64_t steps[] = {kScale, kScale / 2, kScale / 4, kScale / 8};
  for (int i = 0; i < 4000; ++i) {
    const std::int64_t step = steps[rng.uniform(0, 3)];
    const std::int64_t n = 6 * kScale / step;
    batch.push_back({rng.uniform(-n, n) * step, rng.uniform(-n, n) * step, rng.uniform(-n, n) * step,
                     rng.uniform(-n, n) * step});
  }
  checkBatch(batch, kScale);
}

// Exhaustive: all segments between points of a half-cell lattice on [-1, 2]^2 (7x7 points)
// and of a quarter-cell lattice on [0, 2]^2 (9x9 points). Every combination of endpoint on
// interior / edge / corner, every direction, every corner passage of short rays.
TEST(TraverseSegmentExact, ExhaustiveSmallLattices) {
  std::vector<LatticeSegment> batch;
  auto addAll = [&batch](std::int64_t lo, std::int64_t hi, std::int64_t step) {
    std::vector<std::pair<std::int64_t, std::int64_t>> points;
    for (std::int64_t x = lo; x <= hi; x += step) {
      for (std::int64_t y = lo; y <= hi; y += step) points.push_back({x, y});
    }
    for (const auto& p : points) {
      for (const auto& q : points) batch.push_back({p.first, p.second, q.first, q.second});
    }
  };
  addAll(-kScale, 2 * kScale, kScale / 2);
  addAll(0, 2 * kScale, kScale / 4);
  checkBatch(batch, kScale);
}

// Rays exactly along horizontal and vertical grid lines, in both directions, with endpoints
// in cell interiors, on cell boundaries or on corners.
TEST(TraverseSegmentExact, RaysAlongGridLines) {
  Rng rng(0x5eed0003);
  std::vector<LatticeSegment> batch;
  for (int i = 0; i < 3000; ++i) {
    const std::int64_t line = coord(rng, 40, true);
    const std::int64_t a = coord(rng, 40, rng.chance(3));
    const std::int64_t b = coord(rng, 40, rng.chance(3));
    if (i % 2 == 0) {
      batch.push_back({a, line, b, line});  // Horizontal, along y = line.
    } else {
      batch.push_back({line, a, line, b});  // Vertical, along x = line.
    }
  }
  // Short ones, where starting / ending on the line edge matters most.
  for (int i = 0; i < 1000; ++i) {
    const std::int64_t line = coord(rng, 3, true);
    const std::int64_t a = coord(rng, 3, rng.chance(2));
    const std::int64_t b = coord(rng, 3, rng.chance(2));
    batch.push_back(i % 2 == 0 ? LatticeSegment{a, line, b, line} : LatticeSegment{line, a, line, b});
  }
  checkBatch(batch, kScale);
}

// Rays through lattice corners: lines P(s) = C + s * (dx, dy) through an integer corner C.
// With (dx, dy) = (+-1, +-1) these are exact 45 degree rays through a corner every cell, in
// all four diagonal directions; other small integer directions pass corners less often.
// Endpoints are random positions on the line (sometimes corners themselves).
TEST(TraverseSegmentExact, RaysThroughCorners) {
  Rng rng(0x5eed0004);
  std::vector<LatticeSegment> batch;
  for (int i = 0; i < 4000; ++i) {
    std::int64_t dx;
    std::int64_t dy;
    if (i % 2 == 0) {
      dx = rng.sign();
      dy = rng.sign();
    } else {
      do {
        dx = rng.uniform(-3, 3);
        dy = rng.uniform(-3, 3);
      } while (dx == 0 || dy == 0);
    }
    const std::int64_t cx = coord(rng, 20, true);
    const std::int64_t cy = coord(rng, 20, true);
    // s in lattice units; a multiple of kScale puts the endpoint on a corner.
    const bool corner_ends = rng.chance(3);
    const std::int64_t s0 = corner_ends ? rng.uniform(-8, 8) * kScale : rng.uniform(-8 * kScale, 8 * kScale);
    const std::int64_t s1 = corner_ends ? rng.uniform(-8, 8) * kScale : rng.uniform(-8 * kScale, 8 * kScale);
    batch.push_back({cx + s0 * dx, cy + s0 * dy, cx + s1 * dx, cy + s1 * dy});
  }
  checkBatch(batch, kScale);
}

// Both endpoints are lattice corners (integer points), any direction.
TEST(TraverseSegmentExact, CornerToCornerRays) {
  Rng rng(0x5eed0005);
  std::vector<LatticeSegment> batch;
  for (int i = 0; i < 2000; ++i) {
    const std::int64_t n = i % 2 == 0 ? 4 : 30;
    batch.push_back({coord(rng, n, true), coord(rng, n, true), coord(rng, n, true), coord(rng, n, true)});
  }
  checkBatch(batch, kScale);
}

// Zero-length segments anywhere: interior points, on edges and on corners.
TEST(TraverseSegmentExact, ZeroLength) {
  Rng rng(0x5eed0006);
  std::vector<LatticeSegment> batch;
  for (int i = 0; i < 1000; ++i) {
    const std::int64_t x = coord(rng, 40, i % 3 == 0);
    const std::int64_t y = coord(rng, 40, i % 5 == 0);
    batch.push_back({x, y, x, y});
  }
  checkBatch(batch, kScale);
}

// Segments starting or ending exactly on a cell boundary (or corner) while moving in the
// negative direction along that axis, plus the positive-direction counterparts.
TEST(TraverseSegmentExact, EndpointsOnBoundariesNegativeDirection) {
  Rng rng(0x5eed0007);
  std::vector<LatticeSegment> batch;
  for (int i = 0; i < 4000; ++i) {
    const std::int64_t n = i % 2 == 0 ? 3 : 20;
    // Which endpoint sits on which boundary is chosen per axis.
    const bool x_on_line = rng.chance(2) || i % 4 == 0;
    const bool y_on_line = rng.chance(2) || i % 4 == 1;
    const bool at_start = rng.chance(2);
    const std::int64_t bx = coord(rng, n, x_on_line);
    const std::int64_t by = coord(rng, n, y_on_line);
    // Offsets towards the other endpoint: mostly negative, sometimes zero or positive.
    auto offset = [&rng, n]() {
      const std::int64_t mag = rng.uniform(0, 2 * n * kScale);
      return rng.chance(4) ? mag : -mag;
    };
    const std::int64_t ox = offset();
    const std::int64_t oy = offset();
    if (at_start) {
      batch.push_back({bx, by, bx + ox, by + oy});  // Start on the boundary, move down.
    } else {
      batch.push_back({bx - ox, by - oy, bx, by});  // End on the boundary, arriving from above.
    }
  }
  checkBatch(batch, kScale);
}

// Very short segments (a few 1/256 steps), which often stay in one cell or cross one edge
// or corner near their endpoints.
TEST(TraverseSegmentExact, VeryShortRays) {
  Rng rng(0x5eed0008);
  std::vector<LatticeSegment> batch;
  for (int i = 0; i < 3000; ++i) {
    // Start near a line or corner half of the time so the short step crosses it.
    const std::int64_t x = i % 2 == 0 ? coord(rng, 10, true) + rng.uniform(-3, 3) : coord(rng, 10);
    const std::int64_t y = i % 4 < 2 ? coord(rng, 10, true) + rng.uniform(-3, 3) : coord(rng, 10);
    batch.push_back({x, y, x + rng.uniform(-8, 8), y + rng.uniform(-8, 8)});
  }
  checkBatch(batch, kScale);
}

// Long rays spanning several hundred cells; exactness must not degrade with length.
TEST(TraverseSegmentExact, LongRays) {
  Rng rng(0x5eed0009);
  std::vector<LatticeSegment> batch;
  for (int i = 0; i < 400; ++i) {
    const bool on_lines = i % 4 == 0;  // Corner-to-corner long rays hit many corners.
    LatticeSegment s{coord(rng, 400, on_lines), coord(rng, 400, on_lines), coord(rng, 400, on_lines),
                     coord(rng, 400, on_lines)};
    if (i % 8 == 1) {  // Exact long 45 degree ray.
      const std::int64_t len = rng.uniform(200, 400) * kScale + rng.uniform(0, kScale - 1);
      s.x1 = s.x0 + rng.sign() * len;
      s.y1 = s.y0 + rng.sign() * len;
    }
    batch.push_back(s);
  }
  checkBatch(batch, kScale);
}

// A finer lattice (1/4096) on top of the default one, to make sure nothing relies on the
// particular resolution of 1/256.
TEST(TraverseSegmentExact, FinerLattice) {
  constexpr std::int64_t kFine = 4096;
  Rng rng(0x5eed000a);
  std::vector<LatticeSegment> batch;
  for (int i = 0; i < 2000; ++i) {
    auto c = [&rng](std::int64_t cells) { return rng.uniform(-cells * kFine, cells * kFine); };
    batch.push_back({c(40), c(40), c(40), c(40)});
  }
  checkBatch(batch, kFine);
}

// ---------------------------------------------------------------------------------------
// 4. Structural properties for arbitrary (non-dyadic) doubles
// ---------------------------------------------------------------------------------------

::testing::AssertionResult hasPathProperties(double u0, double v0, double u1, double v1) {
  const std::vector<CellXY> cells = runTraversal(u0, v0, u1, v1);
  auto fail = [&]() {
    return ::testing::AssertionFailure() << "segment " << segmentString(u0, v0, u1, v1) << ": " << toString(cells)
                                         << "\n  ";
  };
  const CellXY first{static_cast<std::int32_t>(std::floor(u0)), static_cast<std::int32_t>(std::floor(v0))};
  const CellXY last{static_cast<std::int32_t>(std::floor(u1)), static_cast<std::int32_t>(std::floor(v1))};
  if (cells.front() != first) return fail() << "first cell is not floor(start)";
  if (cells.back() != last) return fail() << "last cell is not floor(end)";
  const std::int64_t bound = std::abs(static_cast<std::int64_t>(last.x) - first.x) +
                             std::abs(static_cast<std::int64_t>(last.y) - first.y) + 1;
  if (static_cast<std::int64_t>(cells.size()) > bound) return fail() << "more than |dx|+|dy|+1 cells";
  std::set<std::pair<std::int32_t, std::int32_t>> seen;
  for (std::size_t i = 0; i < cells.size(); ++i) {
    if (!seen.insert({cells[i].x, cells[i].y}).second) return fail() << "cell repeated at index " << i;
    if (i == 0) continue;
    const std::int32_t sx = cells[i].x - cells[i - 1].x;
    const std::int32_t sy = cells[i].y - cells[i - 1].y;
    if (std::abs(sx) > 1 || std::abs(sy) > 1) return fail() << "step not 4/8-connected at index " << i;
    // A straight segment is monotone in each coordinate: steps follow the direction of travel.
    if ((sx > 0 && !(u1 > u0)) || (sx < 0 && !(u1 < u0)) || (sy > 0 && !(v1 > v0)) || (sy < 0 && !(v1 < v0))) {
      return fail() << "step against the direction of travel at index " << i;
    }
  }
  return ::testing::AssertionSuccess();
}

TEST(TraverseSegmentProperties, RandomNonDyadicRays) {
  std::mt19937_64 engine(0x5eed000b);
  std::uniform_real_distribution<double> small(-50.0, 50.0);
  std::uniform_real_distribution<double> large(-500.0, 500.0);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_int_distribution<int> integer(-30, 30);
  // Tiny offsets from integers stress rounding right next to edges and corners.
  const double nudges[] = {0.0, 1e-15, -1e-15, 1e-12, -1e-12, 1e-9, -1e-9, 0.1, -0.1};
  std::uniform_int_distribution<int> nudge_index(0, 8);
  auto nearInteger = [&]() { return integer(engine) + nudges[nudge_index(engine)]; };

  int failures = 0;
  int count = 0;
  auto check = [&](double u0, double v0, double u1, double v1) {
    ++count;
    const ::testing::AssertionResult r = hasPathProperties(u0, v0, u1, v1);
    if (!r) {
      if (failures < 8) ADD_FAILURE() << r.message();
      ++failures;
    }
  };
  for (int i = 0; i < 6000; ++i) check(small(engine), small(engine), small(engine), small(engine));
  for (int i = 0; i < 500; ++i) check(large(engine), large(engine), large(engine), large(engine));
  for (int i = 0; i < 4000; ++i) check(nearInteger(), nearInteger(), nearInteger(), nearInteger());
  // Almost-diagonal rays through (almost) corners, in all four directions.
  for (int i = 0; i < 4000; ++i) {
    const double cx = integer(engine) + nudges[nudge_index(engine)];
    const double cy = integer(engine) + nudges[nudge_index(engine)];
    const double sx = (i & 1) ? 1.0 : -1.0;
    const double sy = (i & 2) ? 1.0 : -1.0;
    const double a = -10.0 * unit(engine);
    const double b = 10.0 * unit(engine) * (1.0 + nudges[nudge_index(engine)]);
    check(cx + a * sx, cy + a * sy, cx + b * sx, cy + b * sy);
  }
  // Nearly axis-aligned rays (tiny non-zero slope).
  for (int i = 0; i < 1000; ++i) {
    const double y = nearInteger();
    const double eps = nudges[1 + nudge_index(engine) % 6];
    if (i % 2 == 0) {
      check(small(engine), y, small(engine), y + eps);
    } else {
      check(y, small(engine), y + eps, small(engine));
    }
  }
  EXPECT_EQ(failures, 0) << "of " << count << " segments";
}

}  // namespace
