// Tests of the published layers (core/layers/layers.h): every layer evaluated from cell state
// written directly into a CellGrid, against references computed here (2x2 matrix powers by
// iteration, stationary p_of / (p_of + p_fo), the logistic of the log-odds), NaN for cells
// never observed, the row-major layout, and the one scaling to OccupancyGrid values.

#include "dynamic_occupancy_grid/core/layers/layers.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"
#include "dynamic_occupancy_grid/core/cell/cell_model.h"
#include "dynamic_occupancy_grid/core/grid/mapper.h"

namespace dog = dynamic_occupancy_grid::core;

namespace {

using LD = long double;
using XY = std::pair<std::int32_t, std::int32_t>;

constexpr float kNaNF = std::numeric_limits<float>::quiet_NaN();
constexpr double kTol = 1e-6;

dog::CellBox box(std::int32_t min_x, std::int32_t min_y, std::int32_t max_x, std::int32_t max_y) {
  dog::CellBox b;
  b.min_x = min_x;
  b.min_y = min_y;
  b.max_x = max_x;
  b.max_y = max_y;
  return b;
}

struct Cell {
  float p_occ;
  std::int32_t last_step;
  float log_odds;
  float p_of;
  float p_fo;
};

dog::CellGrid makeGrid() {
  return dog::CellGrid(0.05, 0.0, 0.0, std::nullopt, 1 << 16, dog::CellGrid::CellDefaults{0.01f, 0.02f});
}

void write(dog::CellGrid& grid, std::int32_t x, std::int32_t y, const Cell& c) {
  grid.reserve(box(x, y, x, y));
  dog::CellGrid::Tile* tile = grid.tileForWriting(x, y);
  ASSERT_NE(tile, nullptr);
  const int i = dog::CellGrid::offsetOf(x, y);
  tile->p_occ[i] = c.p_occ;
  tile->last_step[i] = c.last_step;
  tile->log_odds[i] = c.log_odds;
  tile->p_occ_given_free[i] = c.p_of;
  tile->p_free_given_occ[i] = c.p_fo;
}

// p(occ) after k steps without observation: k times q <- q A.
LD iterate(LD p, LD p_of, LD p_fo, std::int64_t k) {
  for (std::int64_t s = 0; s < k; ++s) p = p * (1.0L - p_fo) + (1.0L - p) * p_of;
  return p;
}

LD logistic(LD l) { return 1.0L / (1.0L + std::exp(-l)); }

float valueAt(const std::vector<float>& values, const dog::CellBox& b, std::int32_t x, std::int32_t y) {
  return values[static_cast<std::size_t>((std::int64_t{y} - b.min_y) * b.width() + (x - b.min_x))];
}

// Expected value of `layer` for a cell, written out independently.
double expected(const Cell& c, dog::Layer layer, std::int64_t step, std::int64_t horizon) {
  switch (layer) {
    case dog::Layer::kBelief:
      return static_cast<double>(iterate(c.p_occ, c.p_of, c.p_fo, step - c.last_step));
    case dog::Layer::kPredicted:
      return static_cast<double>(iterate(c.p_occ, c.p_of, c.p_fo, step + horizon - c.last_step));
    case dog::Layer::kStationary:
      if (c.p_of == 0.0f && c.p_fo == 0.0f) return c.p_occ;
      return static_cast<double>(static_cast<LD>(c.p_of) / (static_cast<LD>(c.p_of) + c.p_fo));
    case dog::Layer::kOccGivenFree:
      return c.p_of;
    case dog::Layer::kFreeGivenOcc:
      return c.p_fo;
    case dog::Layer::kStatic:
      return static_cast<double>(logistic(c.log_odds));
  }
  return std::nan("");
}

const std::vector<dog::Layer>& allLayers() {
  static const std::vector<dog::Layer> layers{dog::Layer::kBelief,       dog::Layer::kPredicted,
                                              dog::Layer::kStationary,   dog::Layer::kOccGivenFree,
                                              dog::Layer::kFreeGivenOcc, dog::Layer::kStatic};
  return layers;
}

}  // namespace

TEST(Layers, NamesAreDistinctAndDocumented) {
  EXPECT_EQ(dog::layerName(dog::Layer::kBelief), "belief");
  EXPECT_EQ(dog::layerName(dog::Layer::kPredicted), "predicted");
  EXPECT_EQ(dog::layerName(dog::Layer::kStationary), "stationary");
  std::set<std::string> names;
  for (dog::Layer layer : allLayers()) {
    const std::string name = dog::layerName(layer);
    EXPECT_FALSE(name.empty());
    names.insert(name);
  }
  EXPECT_EQ(names.size(), allLayers().size());
}

TEST(Layers, HandComputedValuesOfOneCell) {
  dog::CellGrid grid = makeGrid();
  // p = 0.8 at step 10, p_of = 0.25, p_fo = 0.375 (lambda = 0.375, pi = 0.4),
  // log-odds ln 3 (p = 0.75).
  write(grid, 3, 4, Cell{0.8f, 10, static_cast<float>(std::log(3.0)), 0.25f, 0.375f});
  const dog::CellBox b = box(3, 4, 3, 4);
  std::vector<float> v;
  // Belief at step 10: the stored value. Step 11: 0.8 * 0.625 + 0.2 * 0.25 = 0.55.
  // Step 12: 0.55 * 0.625 + 0.45 * 0.25 = 0.45625. (pi + lambda^k (0.8 - pi): 0.4 + 0.4 * 0.375^k.)
  dog::evaluateLayer(grid, dog::Layer::kBelief, 10, 0, b, &v);
  ASSERT_EQ(v.size(), 1u);
  EXPECT_NEAR(v[0], 0.8, kTol);
  dog::evaluateLayer(grid, dog::Layer::kBelief, 11, 0, b, &v);
  EXPECT_NEAR(v[0], 0.55, kTol);
  dog::evaluateLayer(grid, dog::Layer::kBelief, 12, 0, b, &v);
  EXPECT_NEAR(v[0], 0.45625, kTol);
  dog::evaluateLayer(grid, dog::Layer::kBelief, 1000, 0, b, &v);
  EXPECT_NEAR(v[0], 0.4, kTol);
  // Predicted: belief at step + horizon.
  dog::evaluateLayer(grid, dog::Layer::kPredicted, 10, 2, b, &v);
  EXPECT_NEAR(v[0], 0.45625, kTol);
  dog::evaluateLayer(grid, dog::Layer::kPredicted, 11, 1, b, &v);
  EXPECT_NEAR(v[0], 0.45625, kTol);
  dog::evaluateLayer(grid, dog::Layer::kPredicted, 10, 0, b, &v);
  EXPECT_NEAR(v[0], 0.8, kTol);
  dog::evaluateLayer(grid, dog::Layer::kStationary, 10, 0, b, &v);
  EXPECT_NEAR(v[0], 0.4, kTol);
  dog::evaluateLayer(grid, dog::Layer::kOccGivenFree, 10, 0, b, &v);
  EXPECT_EQ(v[0], 0.25f);
  dog::evaluateLayer(grid, dog::Layer::kFreeGivenOcc, 10, 0, b, &v);
  EXPECT_EQ(v[0], 0.375f);
  dog::evaluateLayer(grid, dog::Layer::kStatic, 10, 0, b, &v);
  EXPECT_NEAR(v[0], 0.75, kTol);
}

TEST(Layers, StaticAndOscillatingCells) {
  dog::CellGrid grid = makeGrid();
  write(grid, 0, 0, Cell{0.7f, 2, 0.0f, 0.0f, 0.0f});    // A = I: stays 0.7 forever
  write(grid, 1, 0, Cell{0.9f, 2, 0.0f, 1.0f, 1.0f});    // lambda = -1: flips every step
  write(grid, 2, 0, Cell{0.9f, 2, 0.0f, 0.5f, 0.5f});    // lambda = 0: pi after one step
  write(grid, 3, 0, Cell{0.2f, 2, 0.0f, 0.75f, 0.5f});   // lambda = -0.25, pi = 0.6
  const dog::CellBox b = box(0, 0, 3, 0);
  std::vector<float> v;
  for (std::int64_t step = 2; step <= 9; ++step) {
    SCOPED_TRACE(step);
    dog::evaluateLayer(grid, dog::Layer::kBelief, step, 0, b, &v);
    ASSERT_EQ(v.size(), 4u);
    EXPECT_NEAR(v[0], 0.7, kTol);
    EXPECT_NEAR(v[1], (step - 2) % 2 == 0 ? 0.9 : 0.1, kTol);
    EXPECT_NEAR(v[2], step == 2 ? 0.9 : 0.5, kTol);
    EXPECT_NEAR(v[3], static_cast<double>(iterate(0.2f, 0.75f, 0.5f, step - 2)), kTol);
  }
  dog::evaluateLayer(grid, dog::Layer::kStationary, 5, 0, b, &v);
  EXPECT_NEAR(v[0], 0.7, kTol);  // static cell: its belief
  EXPECT_NEAR(v[1], 0.5, kTol);
  EXPECT_NEAR(v[2], 0.5, kTol);
  EXPECT_NEAR(v[3], 0.6, kTol);
}

TEST(Layers, RandomCellsAllLayersAgainstReference) {
  std::mt19937_64 rng(4242);
  std::uniform_int_distribution<std::int32_t> coord(-150, 150);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  std::uniform_int_distribution<std::int32_t> stepd(0, 20);
  std::uniform_int_distribution<int> kind(0, 9);
  dog::CellGrid grid = makeGrid();
  std::map<XY, Cell> cells;
  for (int i = 0; i < 400; ++i) {
    const std::int32_t x = coord(rng);
    const std::int32_t y = coord(rng);
    Cell c{unit(rng), stepd(rng), unit(rng) * 8.0f - 4.0f, unit(rng) * 0.5f, unit(rng) * 0.5f};
    if (kind(rng) == 0) {  // some static cells
      c.p_of = 0.0f;
      c.p_fo = 0.0f;
    }
    write(grid, x, y, c);
    cells[{x, y}] = c;
  }
  // Allocated-but-unobserved cells too: tiles around them exist.
  const dog::CellBox b = box(-170, -160, 160, 170);  // beyond the allocated tiles on all sides
  const std::int64_t now = 25;
  for (dog::Layer layer : allLayers()) {
    for (std::int64_t horizon : {0, 3}) {
      SCOPED_TRACE(dog::layerName(layer) + " horizon " + std::to_string(horizon));
      std::vector<float> v;
      dog::evaluateLayer(grid, layer, now, horizon, b, &v);
      ASSERT_EQ(v.size(), static_cast<std::size_t>(b.width() * b.height()));
      std::size_t known = 0;
      for (std::int32_t y = b.min_y; y <= b.max_y; ++y) {
        for (std::int32_t x = b.min_x; x <= b.max_x; ++x) {
          const float actual = valueAt(v, b, x, y);
          const auto it = cells.find({x, y});
          if (it == cells.end()) {
            ASSERT_TRUE(std::isnan(actual)) << x << ", " << y;
            continue;
          }
          ++known;
          ASSERT_NEAR(actual, expected(it->second, layer, now, horizon), kTol) << x << ", " << y;
        }
      }
      EXPECT_EQ(known, cells.size());
    }
  }
}

TEST(Layers, SubBoxesAndUnknownAreas) {
  dog::CellGrid grid = makeGrid();
  write(grid, 65, -1, Cell{0.25f, 0, 1.0f, 0.125f, 0.125f});
  std::vector<float> v;
  // A box that starts in the middle of a tile and covers only part of another.
  const dog::CellBox b = box(60, -3, 70, 1);
  dog::evaluateLayer(grid, dog::Layer::kOccGivenFree, 0, 0, b, &v);
  ASSERT_EQ(v.size(), 11u * 5u);
  for (std::size_t i = 0; i < v.size(); ++i) {
    if (i == static_cast<std::size_t>((-1 - (-3)) * 11 + (65 - 60))) {
      EXPECT_EQ(v[i], 0.125f);
    } else {
      EXPECT_TRUE(std::isnan(v[i])) << i;
    }
  }
  // Entirely unallocated area: all NaN, right size.
  dog::evaluateLayer(grid, dog::Layer::kBelief, 0, 0, box(-1000, -1000, -990, -995), &v);
  ASSERT_EQ(v.size(), 11u * 6u);
  for (float f : v) EXPECT_TRUE(std::isnan(f));
  // Empty box: empty output, even if the vector held something before.
  v.assign(5, 1.0f);
  dog::evaluateLayer(grid, dog::Layer::kBelief, 0, 0, dog::CellBox{}, &v);
  EXPECT_TRUE(v.empty());
  // A box at the very end of the int32 range terminates and is unknown.
  const std::int32_t big = std::numeric_limits<std::int32_t>::max();
  dog::evaluateLayer(grid, dog::Layer::kBelief, 0, 0, box(big - 2, 0, big, 1), &v);
  ASSERT_EQ(v.size(), 6u);
  for (float f : v) EXPECT_TRUE(std::isnan(f));
}

// =====================================================================================
// Layers from the mapper: lazily predicted beliefs
// =====================================================================================

TEST(Layers, MapperBeliefAtLaterStepsEqualsStepwiseReference) {
  dog::MapperConfig config;
  config.resolution_m = 0.25;
  config.prior_transitions = dog::TransitionParams{0.2, 0.3};
  config.p_hit_given_occ = 0.7;
  config.p_hit_given_free = 0.2;
  // Each cell's online EM keeps the prior transitions for its first steps: the reference
  // below iterates them.
  config.learner = dog::TransitionLearner::kCellEm;
  dog::Mapper mapper(config);
  dog::Scan scan;
  scan.stamp_s = 0.0;
  scan.laser_pose.x_m = 0.125;
  scan.laser_pose.y_m = 0.125;
  scan.angle_increment_rad = 0.1;
  scan.range_max_m = 10.0;
  scan.ranges_m = {1.0f};  // (0..3, 0) missed, (4, 0) hit
  mapper.integrate(scan);
  mapper.finishStep();
  // Reference of step 0 (float-stored): predicted prior 0.5 * 0.7 + 0.5 * 0.2 = 0.45;
  // hit: 0.45 * 0.7 / (0.45 * 0.7 + 0.55 * 0.2); miss: 0.45 * 0.3 / (0.45 * 0.3 + 0.55 * 0.8).
  const LD hit0 = static_cast<float>(0.45L * 0.7L / (0.45L * 0.7L + 0.55L * 0.2L));
  const LD miss0 = static_cast<float>(0.45L * 0.3L / (0.45L * 0.3L + 0.55L * 0.8L));
  const LD p_of = 0.2f;
  const LD p_fo = 0.3f;
  const dog::CellBox b = box(0, 0, 5, 0);
  for (std::int64_t step = 0; step <= 10; ++step) {
    SCOPED_TRACE(step);
    std::vector<float> v;
    dog::evaluateLayer(mapper.grid(), dog::Layer::kBelief, step, 0, b, &v);
    ASSERT_EQ(v.size(), 6u);
    EXPECT_NEAR(v[4], static_cast<double>(iterate(hit0, p_of, p_fo, step)), kTol);
    for (int x = 0; x < 4; ++x) EXPECT_NEAR(v[x], static_cast<double>(iterate(miss0, p_of, p_fo, step)), kTol);
    EXPECT_TRUE(std::isnan(v[5]));
    EXPECT_NEAR(mapper.beliefAt(4, 0, step), static_cast<double>(iterate(hit0, p_of, p_fo, step)), kTol);
    dog::evaluateLayer(mapper.grid(), dog::Layer::kPredicted, step, 4, b, &v);
    EXPECT_NEAR(v[4], static_cast<double>(iterate(hit0, p_of, p_fo, step + 4)), kTol);
  }
  std::vector<float> v;
  dog::evaluateLayer(mapper.grid(), dog::Layer::kStationary, 3, 0, b, &v);
  EXPECT_NEAR(v[4], 0.4, kTol);
  dog::evaluateLayer(mapper.grid(), dog::Layer::kStatic, 3, 0, b, &v);
  EXPECT_NEAR(v[4], 0.7 / (0.7 + 0.2), kTol);           // logistic(ln(0.7/0.2))
  EXPECT_NEAR(v[0], 0.3 / (0.3 + 0.8), kTol);           // logistic(ln(0.3/0.8))
  dog::evaluateLayer(mapper.grid(), dog::Layer::kOccGivenFree, 3, 0, b, &v);
  EXPECT_EQ(v[4], 0.2f);
  dog::evaluateLayer(mapper.grid(), dog::Layer::kFreeGivenOcc, 3, 0, b, &v);
  EXPECT_EQ(v[4], 0.3f);
}

TEST(Layers, MapperStaticCellStationaryIsItsBelief) {
  dog::MapperConfig config;
  config.resolution_m = 0.25;
  config.prior_transitions = dog::TransitionParams{0.0, 0.0};
  config.learner = dog::TransitionLearner::kCellEm;
  dog::Mapper mapper(config);
  dog::Scan scan;
  scan.laser_pose.x_m = 0.125;
  scan.laser_pose.y_m = 0.125;
  scan.angle_increment_rad = 0.1;
  scan.range_max_m = 10.0;
  scan.ranges_m = {1.0f};
  mapper.integrate(scan);
  mapper.finishStep();
  // A = I, prior 0.5: after one hit p = 0.7 / 0.9.
  const dog::CellBox b = box(4, 0, 4, 0);
  std::vector<float> v;
  for (dog::Layer layer : {dog::Layer::kBelief, dog::Layer::kStationary, dog::Layer::kPredicted}) {
    dog::evaluateLayer(mapper.grid(), layer, 50, 7, b, &v);
    EXPECT_NEAR(v[0], 0.7 / 0.9, kTol) << dog::layerName(layer);
  }
}

// =====================================================================================
// toOccupancyValues
// =====================================================================================

TEST(OccupancyValues, HandPickedValues) {
  const std::vector<float> values{kNaNF, 0.0f, 0.004f, 0.006f, 0.494f, 0.496f, 0.5f, 0.994f,
                                  0.996f, 1.0f, 1.5f, -0.2f, std::numeric_limits<float>::infinity(),
                                  -std::numeric_limits<float>::infinity(), 0.65f, 0.25f};
  const std::vector<std::int8_t> expected{-1, 0, 0, 1, 49, 50, 50, 99, 100, 100, 100, 0, 100, 0, 65, 25};
  std::vector<std::int8_t> occupancy{7, 7, 7};  // resized by the call
  dog::toOccupancyValues(values, 1.0f, &occupancy);
  ASSERT_EQ(occupancy.size(), expected.size());
  for (std::size_t i = 0; i < expected.size(); ++i) {
    EXPECT_EQ(static_cast<int>(occupancy[i]), static_cast<int>(expected[i])) << "value " << values[i];
  }
}

TEST(OccupancyValues, FullScaleForTransitionLayers) {
  // A p_of layer shown with full scale 0.1: 0.03 -> 30, 0.1 -> 100, 0.2 -> 100 (clamped).
  const std::vector<float> values{0.03f, 0.1f, 0.2f, 0.0f, 0.0504f, kNaNF};
  std::vector<std::int8_t> occupancy;
  dog::toOccupancyValues(values, 0.1f, &occupancy);
  const std::vector<std::int8_t> expected{30, 100, 100, 0, 50, -1};
  ASSERT_EQ(occupancy.size(), expected.size());
  for (std::size_t i = 0; i < expected.size(); ++i) EXPECT_EQ(occupancy[i], expected[i]) << i;
  dog::toOccupancyValues({}, 1.0f, &occupancy);
  EXPECT_TRUE(occupancy.empty());
}

TEST(OccupancyValues, RandomValuesMatchRoundedScaling) {
  std::mt19937_64 rng(8);
  std::uniform_real_distribution<double> u(-0.5, 1.5);
  std::uniform_real_distribution<double> scale(0.05, 2.0);
  for (int trial = 0; trial < 200; ++trial) {
    const float full_scale = static_cast<float>(scale(rng));
    std::vector<float> values;
    std::vector<int> expected;
    for (int i = 0; i < 100; ++i) {
      const float v = static_cast<float>(u(rng) * full_scale);
      const double scaled = 100.0 * static_cast<double>(v) / static_cast<double>(full_scale);
      // Stay clear of the .5 rounding boundaries, where float and double may disagree.
      if (std::fabs(scaled - std::floor(scaled) - 0.5) < 1e-3) continue;
      if (i % 17 == 0) {
        values.push_back(kNaNF);
        expected.push_back(-1);
        continue;
      }
      values.push_back(v);
      expected.push_back(static_cast<int>(std::min(100.0, std::max(0.0, std::round(scaled)))));
    }
    std::vector<std::int8_t> occupancy;
    dog::toOccupancyValues(values, full_scale, &occupancy);
    ASSERT_EQ(occupancy.size(), values.size());
    for (std::size_t i = 0; i < values.size(); ++i) {
      ASSERT_EQ(static_cast<int>(occupancy[i]), expected[i]) << "value " << values[i] << " scale " << full_scale;
    }
  }
}

TEST(OccupancyValues, ThresholdsLikeMapServer) {
  // map_server's image_loader on the same probabilities (occupied_thresh 0.65, free_thresh 0.196).
  const std::vector<float> values{kNaNF, 0.0f, 0.19f, 0.2f, 0.425f, 0.64f, 0.66f, 1.0f};
  dog::OccupancyThresholds thresholds;
  std::vector<std::int8_t> occupancy;
  dog::toThresholdedOccupancyValues(values, thresholds, &occupancy);
  EXPECT_EQ(occupancy, (std::vector<std::int8_t>{-1, 0, 0, -1, -1, -1, 100, 100}));
  thresholds.mode = dog::ThresholdMode::kScale;
  dog::toThresholdedOccupancyValues(values, thresholds, &occupancy);
  const auto scaled = [](double p) { return static_cast<std::int8_t>(1.0 + 98.0 * (p - 0.196) / (0.65 - 0.196)); };
  EXPECT_EQ(occupancy, (std::vector<std::int8_t>{-1, 0, 0, scaled(0.2f), scaled(0.425f), scaled(0.64f), 100, 100}));
  EXPECT_EQ(static_cast<int>(scaled(0.2f)), 1);
  EXPECT_EQ(static_cast<int>(scaled(0.64f)), 96);
  thresholds.mode = dog::ThresholdMode::kRaw;
  dog::toThresholdedOccupancyValues(values, thresholds, &occupancy);
  std::vector<std::int8_t> raw;
  dog::toOccupancyValues(values, 1.0f, &raw);
  EXPECT_EQ(occupancy, raw);
}

TEST(OccupancyValues, ThresholdsAreChecked) {
  dog::OccupancyThresholds thresholds;
  EXPECT_NO_THROW(thresholds.validate());
  thresholds.free_thresh = 0.7;
  EXPECT_THROW(thresholds.validate(), std::invalid_argument);
  thresholds.free_thresh = -0.1;
  EXPECT_THROW(thresholds.validate(), std::invalid_argument);
  thresholds.free_thresh = 0.1;
  thresholds.occupied_thresh = 1.1;
  EXPECT_THROW(thresholds.validate(), std::invalid_argument);
}

// =====================================================================================
// layerOccupancy: one pass to int8 values, identical to evaluateLayer + the scalings for
// every cell state (random cells, edge values, cells at the rounding boundaries)
// =====================================================================================

namespace {

// The reference the fast path must reproduce: the float layer, then the scaling.
std::vector<std::int8_t> referenceOccupancy(const dog::CellGrid& grid, dog::Layer layer, std::int64_t step,
                                            std::int64_t horizon, const dog::CellBox& b,
                                            const dog::OccupancyScaling& scaling) {
  std::vector<float> values;
  dog::evaluateLayer(grid, layer, step, horizon, b, &values);
  std::vector<std::int8_t> occupancy;
  if (scaling.thresholds) {
    dog::toThresholdedOccupancyValues(values, *scaling.thresholds, &occupancy);
  } else {
    dog::toOccupancyValues(values, scaling.full_scale, &occupancy);
  }
  return occupancy;
}

dog::OccupancyScaling thresholded(dog::ThresholdMode mode, double free_thresh, double occupied_thresh) {
  dog::OccupancyThresholds thresholds;
  thresholds.mode = mode;
  thresholds.free_thresh = free_thresh;
  thresholds.occupied_thresh = occupied_thresh;
  return dog::OccupancyScaling{1.0f, thresholds};
}

std::string describe(const dog::OccupancyScaling& s) {
  if (!s.thresholds) return "full_scale " + std::to_string(s.full_scale);
  return "mode " + std::to_string(static_cast<int>(s.thresholds->mode)) + " free " +
         std::to_string(s.thresholds->free_thresh) + " occupied " + std::to_string(s.thresholds->occupied_thresh);
}

// Plain 0..100 scalings (probabilities, the transition layers' scales, odd ones) and
// map_server's thresholds, including an invalid pair (free > occupied: no fast path).
std::vector<dog::OccupancyScaling> allScalings() {
  return {dog::OccupancyScaling{1.0f, std::nullopt},
          dog::OccupancyScaling{0.1f, std::nullopt},
          dog::OccupancyScaling{0.05f, std::nullopt},
          dog::OccupancyScaling{0.37f, std::nullopt},
          dog::OccupancyScaling{2.0f, std::nullopt},
          thresholded(dog::ThresholdMode::kTrinary, 0.196, 0.65),
          thresholded(dog::ThresholdMode::kScale, 0.196, 0.65),
          thresholded(dog::ThresholdMode::kRaw, 0.196, 0.65),
          thresholded(dog::ThresholdMode::kTrinary, 0.3, 0.9),
          thresholded(dog::ThresholdMode::kScale, 0.0, 1.0),
          thresholded(dog::ThresholdMode::kScale, 0.45, 0.55),
          thresholded(dog::ThresholdMode::kTrinary, 0.7, 0.6)};
}

// Compares layerOccupancy with the reference for every layer, horizon, scaling, thread
// count and loop (the CPU's best, AVX2 only; the reference loop where asked) given; stops at
// the first difference with the cell's state.
void expectSameAsReference(const dog::CellGrid& grid, const dog::CellBox& b, const std::vector<std::int64_t>& steps,
                           const std::vector<dog::OccupancyScaling>& scalings, const std::vector<unsigned>& threads,
                           const std::vector<dog::Layer>& layers = allLayers(),
                           const std::vector<dog::LayerKernel>& kernels = {dog::LayerKernel::kAuto,
                                                                           dog::LayerKernel::kAvx2}) {
  for (const dog::OccupancyScaling& scaling : scalings) {
    for (dog::Layer layer : layers) {
      for (std::int64_t step : steps) {
        for (std::int64_t horizon : {std::int64_t{0}, std::int64_t{7}}) {
          if (horizon != 0 && layer != dog::Layer::kPredicted) continue;
          const std::vector<std::int8_t> expected = referenceOccupancy(grid, layer, step, horizon, b, scaling);
          for (unsigned t : threads) {
           for (const dog::LayerKernel kernel : kernels) {
            std::vector<std::int8_t> actual{1, 2, 3};  // replaced by the call
            dog::setLayerKernel(kernel);
            dog::layerOccupancy(grid, layer, step, horizon, b, scaling, &actual, t);
            dog::setLayerKernel(dog::LayerKernel::kAuto);
            ASSERT_EQ(actual.size(), expected.size());
            for (std::size_t i = 0; i < expected.size(); ++i) {
              if (actual[i] == expected[i]) continue;
              const std::int32_t x = b.min_x + static_cast<std::int32_t>(i % static_cast<std::size_t>(b.width()));
              const std::int32_t y = b.min_y + static_cast<std::int32_t>(i / static_cast<std::size_t>(b.width()));
              const std::optional<dog::CellState> cell = grid.cell(x, y);
              std::ostringstream state;
              state.precision(17);
              if (cell) {
                state << "p_occ " << cell->p_occ << " last_step " << cell->last_step << " log_odds " << cell->log_odds
                      << " p_of " << cell->p_occ_given_free << " p_fo " << cell->p_free_given_occ;
              } else {
                state << "never observed";
              }
              FAIL() << dog::layerName(layer) << ", step " << step << ", horizon " << horizon << ", "
                     << describe(scaling) << ", threads " << t << ", kernel " << static_cast<int>(kernel) << ": cell ("
                     << x << ", " << y << ") " << static_cast<int>(actual[i]) << " instead of "
                     << static_cast<int>(expected[i]) << "; " << state.str();
            }
           }
          }
        }
      }
    }
  }
}

// A grid whose cells over `b` are all written by cell(x, y).
template <class CellOf>
dog::CellGrid gridOf(const dog::CellBox& b, CellOf&& cell_of) {
  dog::CellGrid grid = makeGrid();
  grid.reserve(b);
  for (std::int32_t y = b.min_y; y <= b.max_y; ++y) {
    for (std::int32_t x = b.min_x; x <= b.max_x; ++x) {
      dog::CellGrid::Tile* tile = grid.tileForWriting(x, y);
      const int i = dog::CellGrid::offsetOf(x, y);
      const Cell c = cell_of(x, y);
      tile->p_occ[i] = c.p_occ;
      tile->last_step[i] = c.last_step;
      tile->log_odds[i] = c.log_odds;
      tile->p_occ_given_free[i] = c.p_of;
      tile->p_free_given_occ[i] = c.p_fo;
    }
  }
  return grid;
}

// Floats in order: key(a) < key(b) iff a < b (-0 just below +0), for non-NaN floats.
std::uint32_t orderedKey(float f) {
  std::uint32_t u;
  std::memcpy(&u, &f, sizeof u);
  return (u & 0x80000000u) != 0 ? ~u : (u | 0x80000000u);
}
float floatOfKey(std::uint32_t key) {
  const std::uint32_t u = (key & 0x80000000u) != 0 ? (key & 0x7FFFFFFFu) : ~key;
  float f;
  std::memcpy(&f, &u, sizeof f);
  return f;
}
// The float n floats above f (below for n < 0).
float floatsAway(float f, int n) { return floatOfKey(orderedKey(f) + static_cast<std::uint32_t>(n)); }

// The first float of every change of g in [from, to] (g monotone or piecewise so, as the
// scalings are), by a scan in steps of `stride` floats and bisection.
template <class G>
std::vector<float> changesOf(G&& g, float from, float to, std::uint32_t stride) {
  std::vector<float> changes;
  for (std::uint32_t k = orderedKey(from); k < orderedKey(to); k += stride) {
    std::uint32_t lo = k;
    std::uint32_t hi = k + stride;
    if (g(floatOfKey(lo)) == g(floatOfKey(hi))) continue;
    while (hi - lo > 1) {
      const std::uint32_t mid = lo + ((hi - lo) / 2);
      (g(floatOfKey(mid)) == g(floatOfKey(lo)) ? lo : hi) = mid;
    }
    changes.push_back(floatOfKey(hi));
  }
  return changes;
}

// Random cell states that reach every path: valid and invalid probabilities, edge values,
// static and oscillating cells, |lambda| near 1, gaps from 0 to beyond 2^30, future last
// steps, never-observed cells; log-odds including +-0, infinities, NaN and subnormals.
class RandomCells {
 public:
  explicit RandomCells(std::uint64_t seed, std::int64_t now) : rng_(seed), now_(now) {}

  Cell operator()(std::int32_t /*x*/, std::int32_t /*y*/) {
    Cell c{probability(), lastStep(), logOdds(), transition(), transition()};
    switch (pick(12)) {
      case 0:  // static
        c.p_of = 0.0f;
        c.p_fo = 0.0f;
        break;
      case 1:  // lambda = -1
        c.p_of = 1.0f;
        c.p_fo = 1.0f;
        break;
      case 2:  // lambda = 0
        c.p_fo = 1.0f - c.p_of;
        break;
      case 3:  // |lambda| within rounding of 1, either sign
        c.p_of = std::ldexp(1.0f, -static_cast<int>(10 + pick(40)));
        c.p_fo = pick(2) == 0 ? std::ldexp(1.0f, -static_cast<int>(10 + pick(40))) : 1.0f - c.p_of;
        break;
      default:
        break;
    }
    return c;
  }

 private:
  std::uint32_t pick(std::uint32_t n) { return static_cast<std::uint32_t>(rng_() % n); }
  float unit() { return std::uniform_real_distribution<float>(0.0f, 1.0f)(rng_); }

  float probability() {
    static const std::vector<float> edges{0.0f, 1.0f, 0.5f, -0.0f, std::numeric_limits<float>::denorm_min(),
                                          std::nextafter(1.0f, 0.0f), std::nextafter(1.0f, 2.0f), -1e-3f,
                                          std::numeric_limits<float>::quiet_NaN(),
                                          std::numeric_limits<float>::infinity()};
    switch (pick(10)) {
      case 0:
        return edges[pick(static_cast<std::uint32_t>(edges.size()))];
      case 1:  // at a rounding boundary of 100 p, a few floats either side
        return floatsAway((static_cast<float>(pick(100)) + 0.5f) / 100.0f, static_cast<int>(pick(9)) - 4);
      default:
        return unit();
    }
  }

  float transition() {
    switch (pick(10)) {
      case 0:
        return std::ldexp(unit(), -static_cast<int>(pick(140)));  // tiny, down to subnormals
      case 1:
        return pick(2) == 0 ? 0.0f : 1.0f;
      case 2:
        return unit();
      case 3:  // outside [0, 1] or NaN: the reference decides
        return pick(3) == 0 ? std::numeric_limits<float>::quiet_NaN() : (pick(2) == 0 ? -0.25f : 1.5f);
      default:
        return 0.5f * unit();
    }
  }

  std::int32_t lastStep() {
    std::int64_t gap = 0;
    switch (pick(14)) {
      case 0:
        return dog::kNeverObserved;
      case 1:
        gap = 0;
        break;
      case 2:
        gap = -static_cast<std::int64_t>(1 + pick(100));  // "future" last step
        break;
      case 3:
        gap = 1 + pick(1000000);
        break;
      case 4: {
        static const std::vector<std::int64_t> large{(1 << 30) - 2, (1 << 30) - 1, 1 << 30, (1 << 30) + 1,
                                                     std::int64_t{1} << 31, 3000000000LL};
        gap = large[pick(static_cast<std::uint32_t>(large.size()))];
        break;
      }
      case 5:
        gap = 1 + pick(10000);
        break;
      default:
        gap = 1 + pick(100);
        break;
    }
    const std::int64_t last = now_ - gap;
    return static_cast<std::int32_t>(std::clamp<std::int64_t>(last, std::numeric_limits<std::int32_t>::min() + 1,
                                                              std::numeric_limits<std::int32_t>::max()));
  }

  float logOdds() {
    static const std::vector<float> edges{0.0f,
                                          -0.0f,
                                          std::numeric_limits<float>::infinity(),
                                          -std::numeric_limits<float>::infinity(),
                                          std::numeric_limits<float>::quiet_NaN(),
                                          std::numeric_limits<float>::denorm_min(),
                                          -std::numeric_limits<float>::denorm_min(),
                                          1e-30f,
                                          -1e-30f,
                                          100.0f,
                                          -100.0f,
                                          3.5f,
                                          -2.0f};
    switch (pick(8)) {
      case 0:
        return edges[pick(static_cast<std::uint32_t>(edges.size()))];
      case 1: {  // at a rounding boundary of 100 logistic(l)
        const double p = (pick(100) + 0.5) / 100.0;
        return floatsAway(static_cast<float>(std::log(p / (1.0 - p))), static_cast<int>(pick(41)) - 20);
      }
      default:
        return std::uniform_real_distribution<float>(-6.0f, 6.0f)(rng_);
    }
  }

  std::mt19937_64 rng_;
  std::int64_t now_;
};

}  // namespace

TEST(LayerOccupancy, RandomCellsAllLayersAndScalingsMatchReference) {
  // A box that starts and ends inside tiles (runs of every length, tails, partial tiles).
  const dog::CellBox b = box(-70, -3, 130, 140);
  for (std::uint64_t seed = 1; seed <= 6; ++seed) {
    SCOPED_TRACE(seed);
    const std::int64_t now = 100000;
    const dog::CellGrid grid = gridOf(b, RandomCells(seed, now));
    expectSameAsReference(grid, b, {now}, allScalings(), {1});
  }
}

TEST(LayerOccupancy, StepsAtTheEndsOfTheRange) {
  // Steps near the int32 limits and beyond them (the prediction's fast path needs the step
  // and the gap in int32; otherwise the reference decides), with cells relative to them.
  const dog::CellBox b = box(0, 0, 99, 69);
  for (const std::int64_t now : {std::int64_t{0}, std::int64_t{-5}, std::int64_t{std::numeric_limits<std::int32_t>::max()} - 3,
                                 std::int64_t{std::numeric_limits<std::int32_t>::max()} + 10,
                                 std::int64_t{std::numeric_limits<std::int32_t>::min()} + 2}) {
    SCOPED_TRACE(now);
    const dog::CellGrid grid = gridOf(b, RandomCells(77 + static_cast<std::uint64_t>(now & 0xFF), now));
    expectSameAsReference(grid, b, {now, now + 1, now - 1000}, {dog::OccupancyScaling{}, allScalings()[5]}, {1},
                          {dog::Layer::kBelief, dog::Layer::kPredicted});
  }
}

TEST(LayerOccupancy, PredictionsAtTheRoundingBoundaries) {
  // Cells whose predicted belief lands within a float of a boundary of round(100 p) (or of a
  // threshold): p chosen so that pi + lambda^gap (p - pi) hits the boundary, and the floats
  // around it. Most of these lie inside the fast path's guard band and go to the reference;
  // the rest must be decided exactly.
  std::mt19937_64 rng(99);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const std::int64_t now = 1 << 30;
  std::vector<Cell> cells;
  const std::vector<double> targets = [] {
    std::vector<double> t;
    for (int k = 1; k <= 100; ++k) t.push_back((k - 0.5) / 100.0);
    t.push_back(0.196);
    t.push_back(0.65);
    return t;
  }();
  while (cells.size() < 120000) {
    // Half of them with |lambda| near 1 and long gaps (up to 2^30 - 1), where lambda^gap by
    // squaring and the reference's exp(gap log1p(-p_of - p_fo)) differ the most.
    const bool slow = cells.size() % 2 == 0;
    const double scale = slow ? std::pow(10.0, -3.0 - 6.0 * unit(rng)) : (rng() % 2 == 0 ? 0.3 : 1.0);
    const float p_of = static_cast<float>(unit(rng) * scale);
    const float p_fo = static_cast<float>(unit(rng) * scale);
    const std::int64_t gap =
        slow ? std::min<std::int64_t>((1 << 30) - 1, static_cast<std::int64_t>(unit(rng) * 3.0 / (p_of + p_fo + 1e-30)))
             : 1 + static_cast<std::int64_t>(rng() % (rng() % 4 == 0 ? 3000 : 40));
    if (gap < 1) continue;
    const dog::TransitionParams params{p_of, p_fo};
    const double power = dog::lambdaPower(params, gap);
    if (std::abs(power) < 1e-2 || params.isStatic()) continue;
    const double pi = p_of / (static_cast<double>(p_of) + p_fo);
    const double target = targets[rng() % targets.size()];
    const double p = pi + ((target - pi) / power);
    if (!(p >= 0.0 && p <= 1.0)) continue;
    for (int d = -3; d <= 3; ++d) {
      cells.push_back(Cell{floatsAway(static_cast<float>(p), d), static_cast<std::int32_t>(now - gap), 0.0f, p_of, p_fo});
    }
  }
  const std::int32_t side = 250;
  const dog::CellBox b = box(0, 0, side - 1, static_cast<std::int32_t>(cells.size() / side) - 1);
  const dog::CellGrid grid = gridOf(b, [&](std::int32_t x, std::int32_t y) { return cells[y * side + x]; });
  expectSameAsReference(grid, b, {now}, allScalings(), {1}, {dog::Layer::kBelief});
  // ... and a step later the same cells are just off the boundaries (a decided case).
  expectSameAsReference(grid, b, {now + 1}, {dog::OccupancyScaling{}}, {1}, {dog::Layer::kBelief});
}

TEST(LayerOccupancy, StoredValuesAtEveryBoundary) {
  // Layers that are stored floats (belief at its last step, p_of, p_fo; the stationary layer
  // of a static cell): every float within 64 of each boundary of every scaling.
  std::vector<float> values;
  for (const dog::OccupancyScaling& scaling : allScalings()) {
    const auto g = [&](float v) {
      return scaling.thresholds ? dog::thresholdedOccupancyValue(v, *scaling.thresholds)
                                : dog::occupancyValue(v, scaling.full_scale);
    };
    for (const float change : changesOf(g, -0.5f, 2.5f, 1u << 12)) {
      for (int d = -64; d <= 64; ++d) values.push_back(floatsAway(change, d));
    }
  }
  ASSERT_GT(values.size(), 100000u);
  const std::int32_t side = 256;
  const std::int32_t rows = static_cast<std::int32_t>((values.size() + side - 1) / side);
  const dog::CellBox b = box(0, 0, side - 1, rows - 1);
  const std::int64_t now = 3;
  const dog::CellGrid grid = gridOf(b, [&](std::int32_t x, std::int32_t y) {
    const std::size_t i = (static_cast<std::size_t>(y) * side) + x;
    const float v = i < values.size() ? values[i] : 0.5f;
    // gap 0: the belief is p_occ; p_fo = 0 except where v is negative.
    return Cell{v, static_cast<std::int32_t>(now), 0.0f, v, i % 3 == 0 ? v : 0.0f};
  });
  expectSameAsReference(grid, b, {now}, allScalings(), {1},
                        {dog::Layer::kBelief, dog::Layer::kOccGivenFree, dog::Layer::kFreeGivenOcc,
                         dog::Layer::kStationary});
}

TEST(LayerOccupancy, StaticMapAroundEveryBoundary) {
  // static_map is looked up by the float pattern of the log-odds, 4096 patterns per table
  // entry: floats within 4096 of each boundary of each scaling (the entries holding a
  // boundary and their neighbours; every float within 256), found with the reference.
  for (const dog::OccupancyScaling& scaling : {dog::OccupancyScaling{}, allScalings()[1], allScalings()[5],
                                               allScalings()[6], allScalings()[8]}) {
    SCOPED_TRACE(describe(scaling));
    const auto g = [&](float l) {
      const float p = static_cast<float>(dog::logOddsToProbability(l));
      return scaling.thresholds ? dog::thresholdedOccupancyValue(p, *scaling.thresholds)
                                : dog::occupancyValue(p, scaling.full_scale);
    };
    std::vector<float> values;
    for (const float change : changesOf(g, -20.0f, 20.0f, 1u << 14)) {
      for (int d = -4096; d <= 4096; d += (std::abs(d) < 256 ? 1 : 7)) values.push_back(floatsAway(change, d));
    }
    ASSERT_GT(values.size(), 1000u);
    const std::int32_t side = 512;
    const std::int32_t rows = static_cast<std::int32_t>((values.size() + side - 1) / side);
    const dog::CellBox b = box(0, 0, side - 1, rows - 1);
    const dog::CellGrid grid = gridOf(b, [&](std::int32_t x, std::int32_t y) {
      const std::size_t i = (static_cast<std::size_t>(y) * side) + x;
      return Cell{0.5f, 1, i < values.size() ? values[i] : 0.0f, 0.1f, 0.1f};
    });
    expectSameAsReference(grid, b, {1}, {scaling}, {1, 2}, {dog::Layer::kStatic});
  }
}

TEST(LayerOccupancy, ThreadsAndUnallocatedTiles) {
  // A box over 512 x 512 cells (split over threads), partly outside the allocated tiles, with
  // a hole of unobserved cells in the middle: the same for 1, 2, 3 and 0 (per core) threads.
  RandomCells random(5, 700);
  const dog::CellBox written = box(-300, -260, 340, 330);
  dog::CellGrid grid = gridOf(written, [&](std::int32_t x, std::int32_t y) {
    Cell c = random(x, y);
    if (std::abs(x) < 40 && std::abs(y) < 30) c.last_step = dog::kNeverObserved;
    return c;
  });
  const dog::CellBox b = box(-380, -300, 420, 350);
  expectSameAsReference(grid, b, {700}, {dog::OccupancyScaling{}, allScalings()[5]}, {1, 2, 3, 0},
                        {dog::Layer::kBelief, dog::Layer::kStatic, dog::Layer::kOccGivenFree},
                        {dog::LayerKernel::kAuto, dog::LayerKernel::kAvx2, dog::LayerKernel::kReference});
}

TEST(LayerOccupancy, EmptyUnknownAndEdgeBoxes) {
  dog::CellGrid grid = makeGrid();
  write(grid, 65, -1, Cell{0.25f, 0, 1.0f, 0.125f, 0.125f});
  std::vector<std::int8_t> v{4, 5};
  dog::layerOccupancy(grid, dog::Layer::kBelief, 0, 0, dog::CellBox{}, dog::OccupancyScaling{}, &v);
  EXPECT_TRUE(v.empty());
  dog::layerOccupancy(grid, dog::Layer::kBelief, 0, 0, box(-1000, -1000, -990, -995), dog::OccupancyScaling{}, &v);
  EXPECT_EQ(v, std::vector<std::int8_t>(66, -1));
  const std::int32_t big = std::numeric_limits<std::int32_t>::max();
  dog::layerOccupancy(grid, dog::Layer::kStatic, 0, 0, box(big - 2, big - 1, big, big), dog::OccupancyScaling{}, &v);
  EXPECT_EQ(v, std::vector<std::int8_t>(6, -1));
  const std::int32_t small = std::numeric_limits<std::int32_t>::min();
  dog::layerOccupancy(grid, dog::Layer::kStatic, 0, 0, box(small, small, small + 2, small + 1), dog::OccupancyScaling{},
                      &v);
  EXPECT_EQ(v, std::vector<std::int8_t>(6, -1));
  // The one cell: belief 25, p_of 12.5 -> 13 at full scale 1 (lround), static logistic(1) -> 73.
  dog::layerOccupancy(grid, dog::Layer::kBelief, 0, 0, box(65, -1, 65, -1), dog::OccupancyScaling{}, &v);
  EXPECT_EQ(v, std::vector<std::int8_t>{25});
  dog::layerOccupancy(grid, dog::Layer::kOccGivenFree, 0, 0, box(64, -1, 66, -1), dog::OccupancyScaling{}, &v);
  EXPECT_EQ(v, (std::vector<std::int8_t>{-1, 13, -1}));
  dog::layerOccupancy(grid, dog::Layer::kStatic, 0, 0, box(65, -1, 65, -1), dog::OccupancyScaling{}, &v);
  EXPECT_EQ(v, std::vector<std::int8_t>{73});
}

TEST(LayerOccupancy, MapperLayersMatchReference) {
  // A mapped scene (not hand-written cells): the mapper's own states after some steps.
  dog::MapperConfig config;
  config.resolution_m = 0.1;
  dog::Mapper mapper(config);
  std::mt19937_64 rng(3);
  for (int step = 0; step < 30; ++step) {
    dog::Scan scan;
    scan.stamp_s = step;
    scan.laser_pose.x_m = 0.05 * step;
    scan.laser_pose.y_m = 0.03;
    scan.angle_min_rad = -2.0;
    scan.angle_increment_rad = 0.01;
    scan.range_max_m = 12.0;
    for (int i = 0; i < 400; ++i) scan.ranges_m.push_back(2.0f + static_cast<float>(rng() % 800) / 100.0f);
    mapper.integrate(scan);
    mapper.finishStep();
  }
  const dog::CellBox b = mapper.grid().bounds();
  expectSameAsReference(mapper.grid(), b, {29, 40, 500}, allScalings(), {1, 2}, allLayers(),
                        {dog::LayerKernel::kAuto, dog::LayerKernel::kAvx2, dog::LayerKernel::kReference});
}

// =====================================================================================
// LayerTileCache: per-tile int8 values of the step-independent layers
// =====================================================================================

TEST(LayerTileCache, CopiesWhatLayerOccupancyGivesAndRecomputesBumpedTiles) {
  RandomCells random(21, 50);
  const dog::CellBox written = box(-150, -100, 260, 200);
  dog::CellGrid grid = gridOf(written, random);
  const dog::CellBox b = box(-200, -130, 300, 230);  // beyond the tiles: -1 there
  const dog::OccupancyScaling thresholds = allScalings()[5];
  for (const dog::Layer layer :
       {dog::Layer::kStatic, dog::Layer::kOccGivenFree, dog::Layer::kFreeGivenOcc, dog::Layer::kStationary}) {
    for (const dog::OccupancyScaling& scaling : {dog::OccupancyScaling{}, dog::OccupancyScaling{0.1f, std::nullopt}, thresholds}) {
      SCOPED_TRACE(dog::layerName(layer) + ", " + describe(scaling));
      dog::TileVersions versions;
      dog::LayerTileCache cache(layer, scaling);
      std::vector<std::int8_t> expected;
      std::vector<std::int8_t> cached;
      dog::layerOccupancy(grid, layer, 50, 0, b, scaling, &expected);
      cache.occupancy(grid, versions, b, &cached);
      EXPECT_EQ(cached, expected);
      const std::size_t tiles = cache.tiles();
      EXPECT_EQ(cache.lastComputed(), tiles);
      EXPECT_EQ(tiles, grid.allocatedTiles());  // every allocated tile of the box: 8 x 6
      EXPECT_EQ(tiles, 48u);
      // Nothing written: all copied.
      cache.occupancy(grid, versions, b, &cached, 2);
      EXPECT_EQ(cache.lastComputed(), 0u);
      EXPECT_EQ(cached, expected);
      // A sub-box: the same values.
      const dog::CellBox sub = box(-70, 3, 100, 90);
      std::vector<std::int8_t> sub_expected;
      dog::layerOccupancy(grid, layer, 50, 0, sub, scaling, &sub_expected);
      cache.occupancy(grid, versions, sub, &cached);
      EXPECT_EQ(cached, sub_expected);
      EXPECT_EQ(cache.lastComputed(), 0u);
      // Write cells of two tiles and bump them: those two are computed again.
      dog::CellGrid::Tile* tile = grid.findTile(10, 10);
      for (int i = 0; i < dog::CellGrid::kTileCells; i += 3) {
        tile->log_odds[i] = -tile->log_odds[i];
        tile->p_occ_given_free[i] = 0.5f * tile->p_occ_given_free[i];
        tile->p_free_given_occ[i] = 1.0f - tile->p_free_given_occ[i];
        tile->p_occ[i] = 1.0f - tile->p_occ[i];
      }
      versions.bump(0, 0);
      grid.findTile(-150, 200)->log_odds[7] = 3.0f;
      grid.findTile(-150, 200)->p_occ_given_free[7] = 0.03f;
      versions.bump(-150 >> 6, 200 >> 6);
      dog::layerOccupancy(grid, layer, 50, 0, b, scaling, &expected);
      cache.occupancy(grid, versions, b, &cached);
      EXPECT_EQ(cache.lastComputed(), 2u);
      EXPECT_EQ(cached, expected);
      // Everything may have changed: all computed again, same values.
      versions.bumpAll();
      cache.occupancy(grid, versions, b, &cached);
      EXPECT_EQ(cache.lastComputed(), tiles);
      EXPECT_EQ(cached, expected);
      // A grid made anew (new tiles) for the next round.
      grid = gridOf(written, RandomCells(21, 50));
    }
  }
}

TEST(LayerTileCache, RefusesLayersOfTheStep) {
  EXPECT_THROW(dog::LayerTileCache(dog::Layer::kBelief, dog::OccupancyScaling{}), std::invalid_argument);
  EXPECT_THROW(dog::LayerTileCache(dog::Layer::kPredicted, dog::OccupancyScaling{}), std::invalid_argument);
  dog::LayerTileCache cache(dog::Layer::kStatic, dog::OccupancyScaling{});
  const dog::CellGrid grid = makeGrid();
  std::vector<std::int8_t> v{1};
  cache.occupancy(grid, dog::TileVersions{}, dog::CellBox{}, &v);
  EXPECT_TRUE(v.empty());
  cache.occupancy(grid, dog::TileVersions{}, box(0, 0, 2, 1), &v);
  EXPECT_EQ(v, std::vector<std::int8_t>(6, -1));
}
