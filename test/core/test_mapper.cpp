// Mapper: reading rules, one count per cell per scan (hit wins), step fusion, the lazy
// closed-form gap against a step-by-step reference, rejected scans changing nothing, and
// the layers read from the result. References are written here from THEORY.md §1–4.

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "dynamic_occupancy_grid/core/layers.h"
#include "dynamic_occupancy_grid/core/mapper.h"

namespace dog = dynamic_occupancy_grid::core;

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Reference HMM step written out on the 2-vector: predict with A, multiply by the
// likelihoods of `hits` and `misses`, normalise.
double referenceFilter(double q_occ, double p_of, double p_fo, double p_hit_occ, double p_hit_free,
                       int hits, int misses) {
  const double pred_occ = q_occ * (1.0 - p_fo) + (1.0 - q_occ) * p_of;
  const double pred_free = q_occ * p_fo + (1.0 - q_occ) * (1.0 - p_of);
  const double l_occ = std::pow(p_hit_occ, hits) * std::pow(1.0 - p_hit_occ, misses);
  const double l_free = std::pow(p_hit_free, hits) * std::pow(1.0 - p_hit_free, misses);
  return pred_occ * l_occ / (pred_occ * l_occ + pred_free * l_free);
}

double referencePredict(double q_occ, double p_of, double p_fo, int steps) {
  for (int k = 0; k < steps; ++k) q_occ = q_occ * (1.0 - p_fo) + (1.0 - q_occ) * p_of;
  return q_occ;
}

dog::MapperConfig quarterMetre() {
  dog::MapperConfig config;
  config.resolution_m = 0.25;
  config.time_step_s = 1.0;
  config.p_hit_given_occ = 0.7;
  config.p_hit_given_free = 0.2;
  config.prior_transitions = dog::TransitionParams{0.2, 0.3};
  config.max_free_range_m = 2.0;
  return config;
}

// A scan of the given beams (angles relative to the laser) from (x, y, yaw).
dog::Scan scanOf(double stamp, double x, double y, double yaw, double angle_min, double increment,
                 std::vector<float> ranges, double range_max = 10.0) {
  dog::Scan scan;
  scan.stamp_s = stamp;
  scan.laser_pose = dog::Pose2D{x, y, yaw};
  scan.angle_min_rad = angle_min;
  scan.angle_increment_rad = increment;
  scan.range_min_m = 0.1;
  scan.range_max_m = range_max;
  scan.ranges_m = std::move(ranges);
  return scan;
}

// One beam along +x from the centre of cell (0, 0).
dog::Scan beamX(double stamp, float range) { return scanOf(stamp, 0.125, 0.125, 0.0, 0.0, 0.01, {range}); }

float belief(const dog::Mapper& mapper, int x, int y) {
  const auto cell = mapper.grid().cell(x, y);
  return cell ? cell->p_occ : std::numeric_limits<float>::quiet_NaN();
}

std::vector<float> dump(const dog::Mapper& mapper, dog::Layer layer, std::int64_t step) {
  std::vector<float> values;
  dog::evaluateLayer(mapper.grid(), layer, step, 0, dog::CellBox{-256, -256, 255, 255}, &values);
  return values;
}

bool sameValues(const std::vector<float>& a, const std::vector<float>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (std::isnan(a[i]) != std::isnan(b[i])) return false;
    if (!std::isnan(a[i]) && a[i] != b[i]) return false;
  }
  return true;
}

TEST(MapperReadings, HitBeamMissesUpToTheEndCellAndHitsIt) {
  dog::Mapper mapper(quarterMetre());
  const dog::ScanResult result = mapper.integrate(beamX(0.0, 1.0f));  // end at lattice x = 4.5
  ASSERT_EQ(result.status, dog::ScanStatus::kIntegrated);
  EXPECT_EQ(result.beams_hit, 1u);
  mapper.finishStep();
  const double miss = referenceFilter(0.5, 0.2, 0.3, 0.7, 0.2, 0, 1);
  const double hit = referenceFilter(0.5, 0.2, 0.3, 0.7, 0.2, 1, 0);
  for (int x = 0; x < 4; ++x) EXPECT_NEAR(belief(mapper, x, 0), miss, 1e-6) << x;
  EXPECT_NEAR(belief(mapper, 4, 0), hit, 1e-6);
  EXPECT_TRUE(std::isnan(belief(mapper, 5, 0)));
  EXPECT_TRUE(std::isnan(belief(mapper, 0, 1)));
}

TEST(MapperReadings, NoReturnClearsUpToMaxFreeRangeWithoutHit) {
  for (const float range : {static_cast<float>(kInf), 10.0f, 25.0f}) {
    dog::Mapper mapper(quarterMetre());
    const dog::ScanResult result = mapper.integrate(beamX(0.0, range));
    EXPECT_EQ(result.beams_no_return, 1u);
    EXPECT_EQ(result.beams_hit, 0u);
    mapper.finishStep();
    const double miss = referenceFilter(0.5, 0.2, 0.3, 0.7, 0.2, 0, 1);
    // 2 m = 8 cells from lattice x 0.5: end at 8.5, the end cell is missed too.
    for (int x = 0; x <= 8; ++x) EXPECT_NEAR(belief(mapper, x, 0), miss, 1e-6) << range << " " << x;
    EXPECT_TRUE(std::isnan(belief(mapper, 9, 0)));
  }
}

TEST(MapperReadings, FreeRangeNeverExceedsTheSensorsRangeMax) {
  dog::Mapper mapper(quarterMetre());
  mapper.integrate(scanOf(0.0, 0.125, 0.125, 0.0, 0.0, 0.01, {static_cast<float>(kInf)}, 1.0));
  mapper.finishStep();
  EXPECT_FALSE(std::isnan(belief(mapper, 4, 0)));  // 1 m: end at 4.5
  EXPECT_TRUE(std::isnan(belief(mapper, 5, 0)));
}

TEST(MapperReadings, ZeroMaxFreeRangeIgnoresNoReturnBeams) {
  dog::MapperConfig config = quarterMetre();
  config.max_free_range_m = 0.0;
  dog::Mapper mapper(config);
  const dog::ScanResult result = mapper.integrate(beamX(0.0, static_cast<float>(kInf)));
  EXPECT_EQ(result.beams_no_return, 1u);
  mapper.finishStep();
  EXPECT_TRUE(std::isnan(belief(mapper, 0, 0)));
}

TEST(MapperReadings, NanNegativeInfinityAndShortRangesAreIgnored) {
  dog::Mapper mapper(quarterMetre());
  const dog::ScanResult result = mapper.integrate(scanOf(
      0.0, 0.125, 0.125, 0.0, 0.0, 0.01,
      {static_cast<float>(kNaN), static_cast<float>(-kInf), 0.05f, 0.0f, -1.0f}));
  ASSERT_EQ(result.status, dog::ScanStatus::kIntegrated);
  EXPECT_EQ(result.beams_ignored, 5u);
  EXPECT_EQ(result.beams_hit + result.beams_no_return, 0u);
  mapper.finishStep();
  EXPECT_TRUE(std::isnan(belief(mapper, 0, 0)));
}

TEST(MapperReadings, BeamAnglesFollowYawAndUpsideDownMirrors) {
  // Beam at +90 degrees relative to a laser facing +x ends above the laser; mirrored, below.
  for (const bool upside_down : {false, true}) {
    dog::Mapper mapper(quarterMetre());
    dog::Scan scan = scanOf(0.0, 0.125, 0.125, 0.0, kPi / 2, 0.01, {1.0f});
    scan.upside_down = upside_down;
    mapper.integrate(scan);
    mapper.finishStep();
    const int end_y = upside_down ? -4 : 4;
    EXPECT_GT(belief(mapper, 0, end_y), 0.5f) << upside_down;
    EXPECT_TRUE(std::isnan(belief(mapper, 0, -end_y))) << upside_down;
  }
}

TEST(MapperCounting, OneScanCountsACellOnceAndHitWins) {
  const double one_miss = referenceFilter(0.5, 0.2, 0.3, 0.7, 0.2, 0, 1);
  const double one_hit = referenceFilter(0.5, 0.2, 0.3, 0.7, 0.2, 1, 0);
  // Long beam first (cell 4 missed, then hit by the short one) and the other order.
  for (const auto& ranges : {std::vector<float>{2.0f, 1.0f}, std::vector<float>{1.0f, 2.0f}}) {
    dog::Mapper mapper(quarterMetre());
    mapper.integrate(scanOf(0.0, 0.125, 0.125, 0.0, 0.0, 1e-9, ranges));
    mapper.finishStep();
    for (int x = 0; x < 4; ++x) EXPECT_NEAR(belief(mapper, x, 0), one_miss, 1e-6) << x;
    EXPECT_NEAR(belief(mapper, 4, 0), one_hit, 1e-6);
    EXPECT_NEAR(belief(mapper, 8, 0), one_hit, 1e-6);
    for (int x = 5; x < 8; ++x) EXPECT_NEAR(belief(mapper, x, 0), one_miss, 1e-6) << x;
  }
}

TEST(MapperCounting, ScansOfOneStepFuseTheirCounts) {
  dog::Mapper mapper(quarterMetre());
  mapper.integrate(beamX(0.1, 1.0f));
  mapper.integrate(beamX(0.5, 1.0f));
  mapper.integrate(beamX(0.9, 2.0f));  // cell 4 missed in the third scan
  mapper.finishStep();
  EXPECT_NEAR(belief(mapper, 4, 0), referenceFilter(0.5, 0.2, 0.3, 0.7, 0.2, 2, 1), 1e-6);
  EXPECT_NEAR(belief(mapper, 2, 0), referenceFilter(0.5, 0.2, 0.3, 0.7, 0.2, 0, 3), 1e-6);
  EXPECT_NEAR(belief(mapper, 6, 0), referenceFilter(0.5, 0.2, 0.3, 0.7, 0.2, 0, 1), 1e-6);
  EXPECT_EQ(mapper.grid().cell(4, 0)->last_step, 0);
}

TEST(MapperCounting, StaticBaselineAddsTheStepsEvidenceAndClamps) {
  dog::MapperConfig config = quarterMetre();
  config.static_clamp = dog::LogOddsClamp{-1.0, 2.0};
  dog::Mapper mapper(config);
  const double hit = std::log(0.7 / 0.2);
  const double miss = std::log(0.3 / 0.8);
  double expected = 0.0;
  for (int step = 0; step < 6; ++step) {
    // Steps 0-2: two hits each (clamps at 2.0); steps 3-5: one miss each.
    if (step < 3) {
      mapper.integrate(beamX(step + 0.1, 1.0f));
      mapper.integrate(beamX(step + 0.2, 1.0f));
      expected = std::min(2.0, expected + 2 * hit);
    } else {
      mapper.integrate(beamX(step + 0.1, 2.0f));
      expected = std::max(-1.0, expected + miss);
    }
  }
  mapper.finishStep();
  EXPECT_NEAR(mapper.grid().cell(4, 0)->log_odds, expected, 1e-6);
  const std::vector<float> values = dump(mapper, dog::Layer::kStatic, 5);
  EXPECT_NEAR(values[(256 + 0) * 512 + (256 + 4)], 1.0 / (1.0 + std::exp(-expected)), 1e-6);
}

TEST(MapperLazy, GapAcrossUnobservedStepsEqualsUpdatingEveryStep) {
  for (const int gap : {1, 2, 3, 7, 20}) {
    dog::Mapper mapper(quarterMetre());
    mapper.integrate(beamX(0.5, 1.0f));          // step 0: cell 4 hit
    mapper.integrate(beamX(gap + 0.5, 2.0f));    // step gap: cell 4 missed
    mapper.finishStep();
    double q = referenceFilter(0.5, 0.2, 0.3, 0.7, 0.2, 1, 0);
    q = referencePredict(q, 0.2, 0.3, gap - 1);
    q = referenceFilter(q, 0.2, 0.3, 0.7, 0.2, 0, 1);
    EXPECT_NEAR(belief(mapper, 4, 0), q, 1e-6) << "gap " << gap;
    EXPECT_EQ(mapper.grid().cell(4, 0)->last_step, gap);
    // Reading later without observation == predicting every step.
    for (const int later : {0, 1, 5, 40}) {
      const double expected = referencePredict(q, 0.2, 0.3, later);
      EXPECT_NEAR(mapper.beliefAt(4, 0, gap + later), expected, 1e-6) << gap << " " << later;
      const std::vector<float> values = dump(mapper, dog::Layer::kBelief, gap + later);
      EXPECT_NEAR(values[256 * 512 + 260], expected, 1e-6);
    }
  }
}

TEST(MapperLazy, CellsNotTouchedByAStepKeepTheirState) {
  dog::Mapper mapper(quarterMetre());
  mapper.integrate(beamX(0.5, 2.0f));  // cells 0..8
  mapper.integrate(beamX(3.5, 0.5f));  // step 3: cells 0..2 only
  mapper.finishStep();
  EXPECT_EQ(mapper.grid().cell(1, 0)->last_step, 3);
  EXPECT_EQ(mapper.grid().cell(6, 0)->last_step, 0);
  EXPECT_NEAR(belief(mapper, 6, 0), referenceFilter(0.5, 0.2, 0.3, 0.7, 0.2, 0, 1), 1e-6);
  const dog::CellBox changed = mapper.takeChangedCells();
  EXPECT_EQ(changed.min_x, 0);
  EXPECT_EQ(changed.max_x, 8);
  EXPECT_TRUE(mapper.takeChangedCells().empty());
}

TEST(MapperRejection, InvalidScansAreRejectedAndChangeNothing) {
  std::vector<dog::Scan> bad;
  bad.push_back(scanOf(0.2, 0.125, 0.125, 0.0, 0.0, 0.01, {}));
  bad.push_back(scanOf(kNaN, 0.125, 0.125, 0.0, 0.0, 0.01, {1.0f}));
  bad.push_back(scanOf(0.2, kInf, 0.125, 0.0, 0.0, 0.01, {1.0f}));
  bad.push_back(scanOf(0.2, 0.125, 0.125, kNaN, 0.0, 0.01, {1.0f}));
  bad.push_back(scanOf(0.2, 0.125, 0.125, 0.0, kNaN, 0.01, {1.0f}));
  bad.push_back(scanOf(0.2, 0.125, 0.125, 0.0, 0.0, 0.0, {1.0f, 1.0f}));
  bad.push_back(scanOf(0.2, 1e12, 0.125, 0.0, 0.0, 0.01, {1.0f}));
  bad.push_back(scanOf(0.2, 0.125, 0.125, 0.0, 0.0, 0.01, {1e30f}, 1e31));
  dog::Scan negative_min = beamX(0.2, 1.0f);
  negative_min.range_min_m = -1.0;
  bad.push_back(negative_min);
  dog::Scan inverted = beamX(0.2, 1.0f);
  inverted.range_max_m = 0.05;
  bad.push_back(inverted);

  // A bad scan first, before any good one, must not start the clock either.
  for (const dog::Scan& scan : bad) {
    dog::Mapper clean(quarterMetre());
    dog::Mapper tested(quarterMetre());
    dog::Scan first_bad = scan;
    first_bad.stamp_s = std::isnan(scan.stamp_s) ? scan.stamp_s : 100.0;
    const dog::ScanResult early = tested.integrate(first_bad);
    EXPECT_EQ(early.status, dog::ScanStatus::kRejectedInvalid);
    EXPECT_FALSE(early.error.empty());
    EXPECT_FALSE(tested.clock().origin().has_value());
    for (dog::Mapper* mapper : {&clean, &tested}) mapper->integrate(beamX(0.1, 1.0f));
    const dog::ScanResult late = tested.integrate(scan);
    EXPECT_EQ(late.status, dog::ScanStatus::kRejectedInvalid) << late.error;
    for (dog::Mapper* mapper : {&clean, &tested}) {
      mapper->integrate(beamX(1.1, 2.0f));
      mapper->finishStep();
    }
    EXPECT_TRUE(sameValues(dump(clean, dog::Layer::kBelief, 1), dump(tested, dog::Layer::kBelief, 1)));
    EXPECT_TRUE(sameValues(dump(clean, dog::Layer::kStatic, 1), dump(tested, dog::Layer::kStatic, 1)));
  }
}

TEST(MapperRejection, TimeGoingBackwardsIsRejected) {
  dog::Mapper mapper(quarterMetre());
  ASSERT_EQ(mapper.integrate(beamX(10.0, 1.0f)).status, dog::ScanStatus::kIntegrated);
  ASSERT_EQ(mapper.integrate(beamX(13.2, 1.0f)).status, dog::ScanStatus::kIntegrated);  // step 3
  // Out of order within the open step is fine; an earlier step is not.
  EXPECT_EQ(mapper.integrate(beamX(13.1, 1.0f)).status, dog::ScanStatus::kIntegrated);
  const dog::ScanResult back = mapper.integrate(beamX(12.9, 2.0f));
  EXPECT_EQ(back.status, dog::ScanStatus::kRejectedTimeBackwards);
  EXPECT_FALSE(back.error.empty());
  mapper.finishStep();
  // The closed step accepts nothing more; the next one does.
  EXPECT_EQ(mapper.integrate(beamX(13.5, 1.0f)).status, dog::ScanStatus::kRejectedTimeBackwards);
  EXPECT_EQ(mapper.integrate(beamX(14.0, 1.0f)).status, dog::ScanStatus::kIntegrated);
  mapper.finishStep();
  // Cell 6 was only reached by the rejected beam.
  EXPECT_TRUE(std::isnan(belief(mapper, 6, 0)));
  EXPECT_EQ(mapper.lastAppliedStep(), 4);
}

TEST(MapperConfigValidation, BadValuesThrowNamingTheParameter) {
  const auto message = [](auto change) {
    dog::MapperConfig config;
    change(config);
    try {
      dog::Mapper mapper(config);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message([](dog::MapperConfig& c) { c.resolution_m = 0.0; }).find("resolution"), std::string::npos);
  EXPECT_NE(message([](dog::MapperConfig& c) { c.time_step_s = -1.0; }).find("time_step"), std::string::npos);
  EXPECT_NE(message([](dog::MapperConfig& c) { c.prior_transitions.p_occ_given_free = 1.5; })
                .find("p_occ_given_free"),
            std::string::npos);
  EXPECT_NE(message([](dog::MapperConfig& c) { c.p_hit_given_free = 0.9; }).find("p_hit_given_occ"),
            std::string::npos);
  EXPECT_NE(message([](dog::MapperConfig& c) { c.max_free_range_m = kNaN; }).find("max_free_range"),
            std::string::npos);
  EXPECT_NE(message([](dog::MapperConfig& c) { c.initial_p_occ = 1.0; }).find("initial_p_occ"),
            std::string::npos);
  EXPECT_EQ(message([](dog::MapperConfig&) {}), "no error");
}

TEST(MapperScenario, WallIsOccupiedFreeSpaceFreeBehindUnknownThenTheWallGoes) {
  dog::MapperConfig config;
  config.resolution_m = 0.1;
  config.prior_transitions = dog::TransitionParams{0.05, 0.05};
  config.max_free_range_m = 3.0;
  dog::Mapper mapper(config);
  // Laser at (0.05, 1.05) facing +x, 61 beams over +-0.3 rad; a wall at x = 1.0 m.
  const double x0 = 0.05;
  const auto wall_scan = [&](double stamp, bool wall) {
    std::vector<float> ranges;
    for (int i = 0; i < 61; ++i) {
      const double angle = -0.3 + 0.01 * i;
      ranges.push_back(wall ? static_cast<float>((1.0 + 0.05 - x0) / std::cos(angle))
                            : static_cast<float>(kInf));
    }
    return scanOf(stamp, x0, 1.05, 0.0, -0.3, 0.01, ranges, 5.0);
  };
  for (int step = 0; step < 5; ++step) mapper.integrate(wall_scan(step + 0.5, true));
  mapper.finishStep();
  EXPECT_GT(belief(mapper, 10, 10), 0.5f);  // the wall cell straight ahead
  EXPECT_GT(belief(mapper, 10, 12), 0.5f);
  EXPECT_LT(belief(mapper, 5, 10), 0.5f);   // between laser and wall
  EXPECT_TRUE(std::isnan(belief(mapper, 13, 10)));  // behind the wall
  // The wall goes: beams now pass through and clear.
  int steps_until_free = 0;
  for (int step = 5; step < 30 && belief(mapper, 10, 10) > 0.5f; ++step) {
    mapper.integrate(wall_scan(step + 0.5, false));
    mapper.finishStep();
    ++steps_until_free;
  }
  EXPECT_LT(belief(mapper, 10, 10), 0.5f);
  EXPECT_LE(steps_until_free, 3);
  EXPECT_LT(belief(mapper, 13, 10), 0.5f);  // now seen, free
}

TEST(Layers, EveryLayerReadsItsCellQuantity) {
  dog::MapperConfig config = quarterMetre();
  dog::Mapper mapper(config);
  mapper.integrate(beamX(0.5, 1.0f));
  mapper.finishStep();
  const std::size_t hit_cell = 256 * 512 + 260;
  const double q = belief(mapper, 4, 0);
  EXPECT_NEAR(dump(mapper, dog::Layer::kOccGivenFree, 0)[hit_cell], 0.2, 1e-7);
  EXPECT_NEAR(dump(mapper, dog::Layer::kFreeGivenOcc, 0)[hit_cell], 0.3, 1e-7);
  EXPECT_NEAR(dump(mapper, dog::Layer::kStationary, 0)[hit_cell], 0.2 / 0.5, 1e-7);
  std::vector<float> predicted;
  dog::evaluateLayer(mapper.grid(), dog::Layer::kPredicted, 2, 3, dog::CellBox{4, 0, 4, 0}, &predicted);
  EXPECT_NEAR(predicted[0], referencePredict(q, 0.2, 0.3, 5), 1e-6);
  EXPECT_TRUE(std::isnan(dump(mapper, dog::Layer::kBelief, 0)[256 * 512 + 300]));

  // A static cell's long-run value is its belief.
  config.prior_transitions = dog::TransitionParams{0.0, 0.0};
  dog::Mapper static_mapper(config);
  static_mapper.integrate(beamX(0.5, 1.0f));
  static_mapper.finishStep();
  EXPECT_NEAR(dump(static_mapper, dog::Layer::kStationary, 9)[hit_cell], belief(static_mapper, 4, 0), 1e-7);
}

TEST(Layers, RowMajorWithRowsAlongY) {
  dog::Mapper mapper(quarterMetre());
  mapper.integrate(scanOf(0.5, 0.125, 0.125, 0.0, kPi / 2, 0.01, {1.0f}));  // cell (0, 4) hit
  mapper.finishStep();
  std::vector<float> values;
  dog::evaluateLayer(mapper.grid(), dog::Layer::kBelief, 0, 0, dog::CellBox{-1, -1, 2, 5}, &values);
  ASSERT_EQ(values.size(), 4u * 7u);
  EXPECT_GT(values[(4 + 1) * 4 + (0 + 1)], 0.5f);
  EXPECT_LT(values[(2 + 1) * 4 + (0 + 1)], 0.5f);
  EXPECT_TRUE(std::isnan(values[(4 + 1) * 4 + (1 + 1)]));
}

TEST(Layers, OccupancyValuesScaleRoundAndMarkUnknown) {
  std::vector<std::int8_t> out;
  dog::toOccupancyValues({std::numeric_limits<float>::quiet_NaN(), 0.0f, 0.004f, 0.006f, 0.5f, 1.0f, 1.7f, -0.2f},
                         1.0f, &out);
  EXPECT_EQ(out, (std::vector<std::int8_t>{-1, 0, 0, 1, 50, 100, 100, 0}));
  dog::toOccupancyValues({0.01f, 0.005f}, 0.02f, &out);
  EXPECT_EQ(out, (std::vector<std::int8_t>{50, 25}));
}

}  // namespace
