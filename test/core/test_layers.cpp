// Tests of the published layers (core/layers.h): every layer evaluated from cell state
// written directly into a CellGrid, against references computed here (2x2 matrix powers by
// iteration, stationary p_of / (p_of + p_fo), the logistic of the log-odds), NaN for cells
// never observed, the row-major layout, and the one scaling to OccupancyGrid values.

#include "dynamic_occupancy_grid/core/layers.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "dynamic_occupancy_grid/core/cell_grid.h"
#include "dynamic_occupancy_grid/core/mapper.h"

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
