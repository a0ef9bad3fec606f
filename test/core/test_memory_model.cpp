// The STM/LTM memory model (Morris et al., THEORY.md §8): the update policies against
// numbers worked out by hand from Table I, the view rules, configurations and hypotheses,
// and the whole model against a plain step-by-step reference over random observations.
#include "dynamic_occupancy_grid/core/memory/memory_model.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <map>
#include <random>
#include <stdexcept>
#include <utility>
#include <vector>

namespace dynamic_occupancy_grid {
namespace core {
namespace {

constexpr double kPi = 3.14159265358979323846;

double logit(double p) { return std::log(p / (1.0 - p)); }

// 1 m cells, updates only when asked (update()).
MemoryModelConfig testConfig() {
  MemoryModelConfig config;
  config.resolution_m = 1.0;
  config.update_distance_m = 1.0e6;
  config.initial_mapping_updates = 0;
  return config;
}

// One beam from the middle of cell (x, y) along `angle`, reading `range` (m).
Scan beamScan(double x_m, double y_m, double angle, float range) {
  Scan scan;
  scan.laser_pose = Pose2D{x_m, y_m, angle};
  scan.angle_min_rad = 0.0;
  scan.angle_increment_rad = 0.01;
  scan.range_min_m = 0.1;
  scan.range_max_m = 100.0;
  scan.ranges_m = {range};
  return scan;
}

// A beam along +x from cell (0, 0) ending in cell (end, 0): misses in cells 0..end-1, a hit in end.
Scan rowScan(int end) { return beamScan(0.5, 0.5, 0.0, static_cast<float>(end)); }

// A beam along +x without return: misses in cells 0..10 (max_free_range 10 m).
Scan clearRowScan() { return beamScan(0.5, 0.5, 0.0, std::numeric_limits<float>::infinity()); }

TEST(MemoryModelConfig, RefusesBadFields) {
  const auto refused = [](auto change) {
    MemoryModelConfig config;
    change(config);
    EXPECT_THROW(config.validate(), std::invalid_argument);
  };
  EXPECT_NO_THROW(MemoryModelConfig{}.validate());
  refused([](MemoryModelConfig& c) { c.resolution_m = 0.0; });
  refused([](MemoryModelConfig& c) { c.resolution_m = std::numeric_limits<double>::quiet_NaN(); });
  refused([](MemoryModelConfig& c) { c.stm.l_min = c.stm.l_max; });
  refused([](MemoryModelConfig& c) { c.ltm.l_max = std::numeric_limits<double>::infinity(); });
  refused([](MemoryModelConfig& c) { c.stm.p_hit = 0.5; });
  refused([](MemoryModelConfig& c) { c.ltm.p_hit = 1.0; });
  refused([](MemoryModelConfig& c) { c.ltm.p_miss = 0.5; });
  refused([](MemoryModelConfig& c) { c.stm.p_miss = 0.0; });
  refused([](MemoryModelConfig& c) { c.update_distance_m = 0.0; });
  refused([](MemoryModelConfig& c) { c.initial_mapping_updates = -1; });
  refused([](MemoryModelConfig& c) { c.hypothesis_configurations = 11; });
  refused([](MemoryModelConfig& c) { c.hypothesis_configurations = -1; });
  refused([](MemoryModelConfig& c) { c.max_free_range_m = -1.0; });
  refused([](MemoryModelConfig& c) { c.max_map_size_m = 0.0; });
  refused([](MemoryModelConfig& c) { c.ltm_occupied_log_odds = std::numeric_limits<double>::quiet_NaN(); });
  MemoryModelConfig bad;
  bad.update_distance_m = -1.0;
  EXPECT_THROW(MemoryModel{bad}, std::invalid_argument);
}

TEST(MemoryModel, DefaultsAreTableOne) {
  const MemoryModelConfig config;
  EXPECT_DOUBLE_EQ(config.stm.l_min, 0.40);
  EXPECT_DOUBLE_EQ(config.stm.l_max, 1.28);
  EXPECT_DOUBLE_EQ(config.ltm.l_min, -2.9);
  EXPECT_DOUBLE_EQ(config.ltm.l_max, 4.59);
  for (const MemoryStoreParams& store : {config.stm, config.ltm}) {
    EXPECT_DOUBLE_EQ(store.p_hit, 0.7);
    EXPECT_DOUBLE_EQ(store.p_miss, 0.4);
  }
}

// Table I: a new cell enters STM at 0.40 with its first hit, stands at 0.40 + logit(0.7) =
// 1.247 < 1.28 after its second; the third consecutive hit clamps it at 1.28 and it
// migrates to LTM at 4.59.
TEST(MemoryModel, CellHitInThreeConsecutiveUpdatesMigrates) {
  MemoryModel model(testConfig());
  ASSERT_TRUE(model.integrate(rowScan(3)).integrated);
  MemoryUpdate first = model.update();
  EXPECT_EQ(first.view_hits, 1u);
  EXPECT_EQ(first.view_misses, 3u);
  EXPECT_FALSE(first.configuration.has_value());
  ASSERT_TRUE(model.stmLogOdds(3, 0).has_value());
  EXPECT_NEAR(*model.stmLogOdds(3, 0), 0.40, 1e-6);
  EXPECT_FALSE(model.ltmLogOdds(3, 0).has_value());
  EXPECT_FALSE(model.stmLogOdds(2, 0).has_value());  // missed cells hold nothing
  EXPECT_TRUE(model.observed(2, 0));
  EXPECT_FALSE(model.observed(4, 0));
  EXPECT_EQ(model.stmCells(), 1u);

  model.integrate(rowScan(3));
  EXPECT_FALSE(model.update().configuration.has_value());
  EXPECT_NEAR(*model.stmLogOdds(3, 0), 0.40 + logit(0.7), 1e-6);
  model.integrate(rowScan(3));
  const MemoryUpdate second = model.update();
  ASSERT_TRUE(second.configuration.has_value());
  EXPECT_EQ(*second.configuration, 1u);
  ASSERT_EQ(second.migrated.size(), 1u);
  EXPECT_EQ(second.migrated[0], (CellXY{3, 0}));
  EXPECT_FALSE(model.stmLogOdds(3, 0).has_value());
  ASSERT_TRUE(model.ltmLogOdds(3, 0).has_value());
  EXPECT_NEAR(*model.ltmLogOdds(3, 0), 4.59, 1e-6);
  EXPECT_EQ(model.configurationOf(3, 0), std::optional<std::uint32_t>(1u));
  EXPECT_EQ(model.ltmCells(), 1u);
  EXPECT_EQ(model.stmCells(), 0u);
  EXPECT_EQ(model.updates(), 3);
}

// Eq. (5): a miss resets STM to l_min and the cell stays in STM, so hit, hit, miss, hit does
// not migrate; the next hit, the second after the reset, does.
TEST(MemoryModel, MissBetweenHitsResetsRehearsal) {
  MemoryModel model(testConfig());
  for (int i = 0; i < 2; ++i) {
    model.integrate(rowScan(3));
    model.update();
  }
  model.integrate(rowScan(5));  // cell 3 missed
  model.update();
  ASSERT_TRUE(model.stmLogOdds(3, 0).has_value());
  EXPECT_NEAR(*model.stmLogOdds(3, 0), 0.40, 1e-6);
  model.integrate(rowScan(3));
  EXPECT_FALSE(model.update().configuration.has_value());
  model.integrate(rowScan(3));
  EXPECT_EQ(model.update().migrated, (std::vector<CellXY>{{3, 0}}));
  // An update that does not observe the cell keeps its STM value.
  for (int i = 0; i < 2; ++i) {
    model.integrate(rowScan(7));
    model.update();
  }
  model.integrate(beamScan(0.5, 0.5, kPi / 2.0, 2.0f));  // along +y: cell 7 unobserved
  model.update();
  model.integrate(rowScan(7));
  EXPECT_EQ(model.update().migrated, (std::vector<CellXY>{{7, 0}}));
}

// Eq. (4): each miss adds logit(0.4); the cell is forgotten on the first miss that takes it
// below -2.9, and a hit on the way refreshes it to 4.59.
TEST(MemoryModel, LtmDecaysOnMissesAndIsForgotten) {
  MemoryModel model(testConfig());
  for (int i = 0; i < 3; ++i) {
    model.integrate(rowScan(3));
    model.update();
  }
  ASSERT_TRUE(model.ltmLogOdds(3, 0).has_value());
  double expected = 4.59;
  int misses = 0;
  // Refresh once in the middle.
  for (int i = 0; i < 5; ++i, ++misses) {
    model.integrate(clearRowScan());
    model.update();
    expected += logit(0.4);
    ASSERT_NEAR(*model.ltmLogOdds(3, 0), expected, 1e-5);
  }
  model.integrate(rowScan(3));
  model.update();
  EXPECT_NEAR(*model.ltmLogOdds(3, 0), 4.59, 1e-6);
  expected = 4.59;
  misses = 0;
  std::size_t forgotten = 0;
  while (model.ltmLogOdds(3, 0).has_value()) {
    model.integrate(clearRowScan());
    forgotten = model.update().forgotten;
    ++misses;
    expected += logit(0.4);
    if (expected >= -2.9) {
      ASSERT_NEAR(*model.ltmLogOdds(3, 0), expected, 1e-5);
    }
    ASSERT_LT(misses, 100);
  }
  // 4.59 - n * 0.405 < -2.9 first at n = 19.
  EXPECT_EQ(misses, 19);
  EXPECT_EQ(forgotten, 1u);
  EXPECT_EQ(model.ltmCells(), 0u);
  EXPECT_TRUE(model.configurations().empty());
  EXPECT_FALSE(model.configurationOf(3, 0).has_value());
  // Seen free from now on: a free cell in every grid.
  const CellBox box = model.bounds();
  EXPECT_EQ(model.ltmGrid(box)[3], kGridFree);
}

// The view's eq. (2): logit(0.7) = 0.847 per hit, logit(0.4) = -0.405 per miss; one hit
// outweighs two misses (0.036 > 0) but not three (-0.369 < 0).
TEST(MemoryModel, ViewSumsHitsAndMissesAsLogOdds) {
  for (const int misses : {2, 3}) {
    MemoryModel model(testConfig());
    model.integrate(rowScan(3));
    for (int i = 0; i < misses; ++i) model.integrate(rowScan(5));
    const MemoryUpdate update = model.update();
    EXPECT_EQ(model.stmLogOdds(3, 0).has_value(), misses == 2) << misses << " misses";
    EXPECT_EQ(model.stmCells(), misses == 2 ? 2u : 1u);
    EXPECT_EQ(update.view_hits, misses == 2 ? 2u : 1u);  // cell 5 is a hit too
  }
}

// Within one scan a cell counts once and a hit wins: two beams through cell (2, 0), one
// ending in it, one passing it.
TEST(MemoryModel, HitWinsWithinAScan) {
  MemoryModel model(testConfig());
  Scan scan = rowScan(2);
  scan.ranges_m = {2.0f, 4.0f};
  scan.angle_increment_rad = 1e-9;  // both beams along +x
  const MemoryScanResult result = model.integrate(scan);
  EXPECT_EQ(result.beams_hit, 2u);
  const MemoryUpdate update = model.update();
  EXPECT_EQ(update.view_hits, 2u);    // cells 2 and 4
  EXPECT_EQ(update.view_misses, 3u);  // cells 0, 1, 3 (each once)
  EXPECT_TRUE(model.stmLogOdds(2, 0).has_value());
  EXPECT_NEAR(*model.stmLogOdds(2, 0), 0.40, 1e-6);
}

// Updates happen after update_distance of laser travel, never from turning on the spot.
TEST(MemoryModel, ViewUpdatesAfterTravelledDistance) {
  MemoryModelConfig config = testConfig();
  config.update_distance_m = 1.0;
  MemoryModel model(config);
  for (int i = 0; i < 50; ++i) {
    const MemoryScanResult result = model.integrate(beamScan(0.5, 0.5, 0.1 * i, 3.0f));
    ASSERT_FALSE(result.update.has_value()) << "turning on the spot updated at scan " << i;
  }
  EXPECT_EQ(model.updates(), 0);
  EXPECT_FALSE(model.integrate(beamScan(0.9, 0.5, 0.0, 3.0f)).update.has_value());  // 0.4 m
  EXPECT_NEAR(model.viewDistanceM(), 0.4, 1e-12);
  EXPECT_FALSE(model.integrate(beamScan(0.9, 1.0, 0.0, 3.0f)).update.has_value());  // 0.4 + 0.5 m
  const MemoryScanResult done = model.integrate(beamScan(0.9, 1.1, 0.0, 3.0f));  // 0.4 + 0.5 + 0.1 m
  ASSERT_TRUE(done.update.has_value());
  EXPECT_EQ(done.update->index, 0);
  EXPECT_EQ(model.updates(), 1);
  EXPECT_DOUBLE_EQ(model.viewDistanceM(), 0.0);
}

TEST(MemoryModel, ConfigurationsGroupOneUpdatesMigrations) {
  MemoryModelConfig config = testConfig();
  config.initial_mapping_updates = 3;
  MemoryModel model(config);
  Scan two = rowScan(3);
  two.ranges_m = {3.0f, 3.0f};
  two.angle_increment_rad = kPi / 2.0;  // cells (3, 0) and (0, 3)
  // Updates 0-2: (3, 0) and (0, 3) migrate during initial mapping: the base map.
  for (int i = 0; i < 2; ++i) {
    model.integrate(two);
    model.update();
  }
  model.integrate(two);
  EXPECT_EQ(model.update().configuration, std::optional<std::uint32_t>(0u));
  // Updates 3-5: (5, 0) migrates as configuration 1; updates 6-8: (0, 6) as 2.
  for (int i = 0; i < 3; ++i) {
    model.integrate(rowScan(5));
    model.update();
  }
  EXPECT_EQ(model.configurationOf(5, 0), std::optional<std::uint32_t>(1u));
  for (int i = 0; i < 3; ++i) {
    model.integrate(beamScan(0.5, 0.5, kPi / 2.0, 6.0f));
    model.update();
  }
  EXPECT_EQ(model.configurationOf(0, 6), std::optional<std::uint32_t>(2u));
  EXPECT_EQ(model.configurationOf(3, 0), std::optional<std::uint32_t>(0u));
  // (0, 6)'s beams passed (0, 3): decayed three times, still in the base map.
  EXPECT_EQ(model.configurationOf(0, 3), std::optional<std::uint32_t>(0u));
  EXPECT_NEAR(*model.ltmLogOdds(0, 3), 4.59 + 3.0 * logit(0.4), 1e-5);
  const std::vector<ConfigurationInfo> infos = model.configurations();
  ASSERT_EQ(infos.size(), 3u);
  EXPECT_EQ(infos[0].id, 0u);
  EXPECT_EQ(infos[1].id, 1u);
  EXPECT_EQ(infos[1].created_update, 5);
  EXPECT_EQ(infos[2].created_update, 8);
  EXPECT_EQ(infos[0].cells, 2u);
  // Both base cells were passed by three later beams: (3, 0) by (5, 0)'s, (0, 3) by (0, 6)'s.
  EXPECT_NEAR(infos[0].presence, 1.0 / (1.0 + std::exp(-(4.59 + 3.0 * logit(0.4)))), 1e-6);
  EXPECT_NEAR(infos[2].presence, 1.0 / (1.0 + std::exp(-4.59)), 1e-6);
}

// Base: (2, 1) via a beam along +x from (0.5, 1.5). Configurations 1: (5, 0), 2: (7, 0).
MemoryModel twoConfigurations(int hypothesis_configurations) {
  MemoryModelConfig config = testConfig();
  config.initial_mapping_updates = 3;
  config.hypothesis_configurations = hypothesis_configurations;
  MemoryModel model(config);
  for (int i = 0; i < 3; ++i) {
    model.integrate(beamScan(0.5, 1.5, 0.0, 2.0f));
    model.update();
  }
  for (const int end : {5, 7}) {
    for (int i = 0; i < 3; ++i) {
      model.integrate(rowScan(end));
      model.update();
    }
  }
  return model;
}

TEST(MemoryModel, HypothesesEnumerateConfigurationsWithPresenceWeights) {
  const MemoryModel model = twoConfigurations(4);
  // Configuration 2's beam passed through (5, 0) three times: 4.59 + 3 logit(0.4).
  const double l5 = 4.59 + 3.0 * logit(0.4);
  ASSERT_NEAR(*model.ltmLogOdds(5, 0), l5, 1e-5);
  const double p1 = 1.0 / (1.0 + std::exp(-l5));
  const double p2 = 1.0 / (1.0 + std::exp(-4.59));
  const std::vector<MapHypothesis> hypotheses = model.hypotheses();
  ASSERT_EQ(hypotheses.size(), 4u);
  double sum = 0.0;
  std::map<std::vector<std::uint32_t>, double> weights;
  for (const MapHypothesis& h : hypotheses) {
    sum += h.weight;
    weights[h.configurations] = h.weight;
    EXPECT_EQ(h.configurations.size() + h.excluded.size(), 2u);
  }
  EXPECT_NEAR(sum, 1.0, 1e-12);
  using Ids = std::vector<std::uint32_t>;
  EXPECT_NEAR(weights[Ids({1, 2})], p1 * p2, 1e-6);
  EXPECT_NEAR(weights[Ids({1})], p1 * (1 - p2), 1e-6);
  EXPECT_NEAR(weights[Ids({2})], (1 - p1) * p2, 1e-6);
  EXPECT_NEAR(weights[Ids()], (1 - p1) * (1 - p2), 1e-6);
  EXPECT_EQ(hypotheses.front().configurations, (std::vector<std::uint32_t>{1, 2}));
  for (std::size_t i = 1; i < hypotheses.size(); ++i) EXPECT_GE(hypotheses[i - 1].weight, hypotheses[i].weight);

  // Grids over cells (0..7) x (0..1): hypothesis {2} has (7, 0) occupied, (5, 0) free,
  // the base cell (2, 1) occupied; never-observed cells unknown.
  const CellBox box = model.bounds();
  ASSERT_EQ(box.min_x, 0);
  ASSERT_EQ(box.max_x, 7);
  ASSERT_EQ(box.min_y, 0);
  ASSERT_EQ(box.max_y, 1);
  const auto at = [&box](const std::vector<std::int8_t>& grid, int x, int y) {
    return grid[static_cast<std::size_t>((y - box.min_y) * box.width() + (x - box.min_x))];
  };
  MapHypothesis only2;
  only2.configurations = {2};
  only2.excluded = {1};
  const std::vector<std::int8_t> grid = model.hypothesisGrid(only2, box);
  EXPECT_EQ(at(grid, 7, 0), kGridOccupied);
  EXPECT_EQ(at(grid, 5, 0), kGridFree);
  EXPECT_EQ(at(grid, 2, 1), kGridOccupied);
  EXPECT_EQ(at(grid, 4, 0), kGridFree);
  EXPECT_EQ(at(grid, 3, 1), kGridUnknown);
  const std::vector<std::int8_t> ltm = model.ltmGrid(box);
  EXPECT_EQ(at(ltm, 5, 0), static_cast<std::int8_t>(std::lround(100 * p1)));
  EXPECT_EQ(at(ltm, 7, 0), static_cast<std::int8_t>(std::lround(100 * p2)));
  EXPECT_EQ(at(ltm, 4, 0), kGridFree);
  EXPECT_EQ(at(ltm, 3, 1), kGridUnknown);

}

// Only the newest K configurations are enumerated; older ones count by their LTM value,
// like the base map.
TEST(MemoryModel, HypothesesEnumerateOnlyTheNewestConfigurations) {
  const MemoryModel one = twoConfigurations(1);
  const std::vector<MapHypothesis> hypotheses = one.hypotheses();
  ASSERT_EQ(hypotheses.size(), 2u);
  EXPECT_EQ(hypotheses[0].configurations, (std::vector<std::uint32_t>{2}));
  EXPECT_EQ(hypotheses[1].excluded, (std::vector<std::uint32_t>{2}));
  const CellBox box = one.bounds();
  const std::vector<std::int8_t> grid = one.hypothesisGrid(hypotheses[1], box);
  EXPECT_EQ(grid[5], kGridOccupied);  // configuration 1: LTM log-odds 3.37 > 0
  EXPECT_EQ(grid[7], kGridFree);      // configuration 2: excluded
  MemoryModelConfig none = testConfig();
  none.hypothesis_configurations = 0;
  const MemoryModel empty(none);
  ASSERT_EQ(empty.hypotheses().size(), 1u);  // one hypothesis: the memory as it is
  EXPECT_DOUBLE_EQ(empty.hypotheses()[0].weight, 1.0);
}

TEST(MemoryModel, RefusedScanChangesNothing) {
  MemoryModel model(testConfig());
  model.integrate(rowScan(3));
  Scan bad = rowScan(3);
  bad.laser_pose.x_m = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(model.integrate(bad).integrated);
  bad = rowScan(3);
  bad.ranges_m.clear();
  EXPECT_FALSE(model.integrate(bad).integrated);
  bad = rowScan(3);
  bad.range_max_m = 0.0;
  EXPECT_FALSE(model.integrate(bad).integrated);
  bad = beamScan(2.0e9, 0.5, 0.0, 3.0f);
  const MemoryScanResult far = model.integrate(bad);
  EXPECT_FALSE(far.integrated);
  EXPECT_NE(far.error.find("too far"), std::string::npos);
  const MemoryUpdate update = model.update();
  EXPECT_EQ(update.view_hits, 1u);
  EXPECT_EQ(update.view_misses, 3u);
}

TEST(MemoryModel, CellsBeyondTheMapSizeAreDropped) {
  MemoryModelConfig config = testConfig();
  config.max_map_size_m = 10.0;  // cells -5 .. 4
  MemoryModel model(config);
  const MemoryScanResult result = model.integrate(rowScan(8));
  EXPECT_EQ(result.cells_outside, 4u);  // 5, 6, 7 missed, 8 hit
  model.update();
  EXPECT_EQ(model.bounds().max_x, 4);
}

TEST(MemoryModel, NoReturnBeamsClearUpToMaxFreeRange) {
  MemoryModelConfig config = testConfig();
  config.max_free_range_m = 4.0;
  MemoryModel model(config);
  Scan scan = rowScan(3);
  scan.ranges_m = {std::numeric_limits<float>::infinity()};
  const MemoryScanResult result = model.integrate(scan);
  EXPECT_EQ(result.beams_no_return, 1u);
  const MemoryUpdate update = model.update();
  EXPECT_EQ(update.view_hits, 0u);
  EXPECT_EQ(update.view_misses, 5u);  // cells 0..4 (the end point x = 4.5 lies in cell 4)
}

TEST(MemoryModel, CopiesAreDeep) {
  MemoryModel model(testConfig());
  for (int i = 0; i < 2; ++i) {
    model.integrate(rowScan(3));
    model.update();
  }
  MemoryModel copy(model);
  model.integrate(rowScan(3));
  model.update();
  EXPECT_TRUE(model.ltmLogOdds(3, 0).has_value());
  EXPECT_FALSE(copy.ltmLogOdds(3, 0).has_value());
  EXPECT_TRUE(copy.stmLogOdds(3, 0).has_value());
  copy = model;
  EXPECT_TRUE(copy.ltmLogOdds(3, 0).has_value());
}

// The plain reference: the policies of THEORY.md §8 written out per cell with a std::map,
// one view per update, fed the same random beams (in all four directions, so that negative
// cell indices and several tiles are crossed).
struct ReferenceCell {
  std::optional<double> ltm;
  std::optional<double> stm;
  std::uint32_t configuration = 0;
};

TEST(MemoryModel, MatchesStepByStepReference) {
  MemoryModelConfig config = testConfig();
  config.initial_mapping_updates = 3;
  MemoryModel model(config);
  std::map<std::pair<int, int>, ReferenceCell> reference;
  std::uint32_t next_id = 1;
  std::mt19937 rng(7);
  const double hit = logit(0.7);
  const double miss = logit(0.4);
  for (int u = 0; u < 300; ++u) {
    std::map<std::pair<int, int>, double> view;
    const int scans = 1 + static_cast<int>(rng() % 3);
    for (int s = 0; s < scans; ++s) {
      const int direction = static_cast<int>(rng() % 4);
      const int range = 1 + static_cast<int>(rng() % 90);  // up to 90 cells: several tiles
      const int dx = direction == 0 ? 1 : (direction == 1 ? -1 : 0);
      const int dy = direction == 2 ? 1 : (direction == 3 ? -1 : 0);
      model.integrate(beamScan(0.5, 0.5, direction == 0 ? 0.0 : (direction == 1 ? kPi : (direction == 2 ? kPi / 2 : -kPi / 2)),
                               static_cast<float>(range)));
      for (int k = 0; k <= range; ++k) view[{k * dx, k * dy}] += k == range ? hit : miss;
    }
    const MemoryUpdate update = model.update();
    std::vector<std::pair<int, int>> migrating;
    for (const auto& [cell, evidence] : view) {
      if (evidence == 0.0) continue;
      ReferenceCell& c = reference[cell];
      if (c.ltm) {
        if (evidence > 0) {
          c.ltm = 4.59;
        } else if (*c.ltm + miss < -2.9) {
          c.ltm.reset();
        } else {
          c.ltm = *c.ltm + miss;
        }
      } else if (evidence > 0) {
        if (!c.stm) {
          c.stm = 0.40;
        } else {
          c.stm = std::min(*c.stm + hit, 1.28);
          if (*c.stm >= 1.28) migrating.push_back(cell);
        }
      } else if (c.stm) {
        c.stm = 0.40;
      }
    }
    const std::uint32_t id = u < 3 ? 0 : next_id;
    if (!migrating.empty() && u >= 3) ++next_id;
    for (const auto& cell : migrating) {
      reference[cell].stm.reset();
      reference[cell].ltm = 4.59;
      reference[cell].configuration = id;
    }
    ASSERT_EQ(update.migrated.size(), migrating.size()) << "update " << u;
    if (!migrating.empty()) {
      ASSERT_EQ(update.configuration, std::optional<std::uint32_t>(id));
    }
    // Floats in the model, doubles here: values agree to rounding, and the thresholds
    // are far from every value this sequence reaches (checked by the exact counts above).
    std::size_t ltm_cells = 0;
    std::size_t stm_cells = 0;
    for (const auto& [cell, c] : reference) {
      const std::optional<double> ltm = model.ltmLogOdds(cell.first, cell.second);
      const std::optional<double> stm = model.stmLogOdds(cell.first, cell.second);
      ASSERT_EQ(ltm.has_value(), c.ltm.has_value()) << cell.first << "," << cell.second << " update " << u;
      ASSERT_EQ(stm.has_value(), c.stm.has_value()) << cell.first << "," << cell.second << " update " << u;
      if (c.ltm) {
        ASSERT_NEAR(*ltm, *c.ltm, 1e-4);
        ASSERT_EQ(model.configurationOf(cell.first, cell.second), std::optional<std::uint32_t>(c.configuration));
        ++ltm_cells;
      }
      if (c.stm) {
        ASSERT_NEAR(*stm, *c.stm, 1e-5);
        ++stm_cells;
      }
    }
    ASSERT_EQ(model.ltmCells(), ltm_cells);
    ASSERT_EQ(model.stmCells(), stm_cells);
  }
  EXPECT_GT(model.ltmCells(), 0u);
  EXPECT_GT(next_id, 3u);  // several configurations were made
}

}  // namespace
}  // namespace core
}  // namespace dynamic_occupancy_grid
