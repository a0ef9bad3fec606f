// The simulator's statistics: random numbers, change rates of dynamic cells, scheduled
// events, the laser's geometry and noise, and the scenarios' layouts.
#include "dynamic_occupancy_grid/evaluation/simulator.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <deque>
#include <functional>
#include <limits>
#include <map>
#include <numeric>
#include <set>
#include <stdexcept>
#include <string>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/cell/offline_em.h"

namespace dynamic_occupancy_grid {
namespace evaluation {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Tolerance for an empirical frequency of n Bernoulli(p) trials: 5 standard deviations
// (a false alarm once in 1.7 million runs; the tests are deterministic anyway).
double binomialTolerance(double p, double n) { return 5.0 * std::sqrt(p * (1.0 - p) / n); }

TEST(Rng, SameSeedSameNumbersOtherSeedOthers) {
  Rng a(42);
  Rng b(42);
  Rng c(43);
  int differences = 0;
  for (int i = 0; i < 100; ++i) {
    const std::uint64_t x = a.next();
    EXPECT_EQ(x, b.next());
    differences += x != c.next();
  }
  EXPECT_EQ(differences, 100);
}

TEST(Rng, DistributionsHaveTheirMoments) {
  Rng rng(7);
  const int n = 200000;
  double sum = 0.0;
  double normal_sum = 0.0;
  double normal_squares = 0.0;
  std::array<int, 7> counts{};
  for (int i = 0; i < n; ++i) {
    const double u = rng.uniform();
    ASSERT_GE(u, 0.0);
    ASSERT_LT(u, 1.0);
    sum += u;
    const double z = rng.normal();
    normal_sum += z;
    normal_squares += z * z;
    ++counts[rng.below(7)];
  }
  EXPECT_NEAR(sum / n, 0.5, 5.0 * std::sqrt(1.0 / 12.0 / n));
  EXPECT_NEAR(normal_sum / n, 0.0, 5.0 / std::sqrt(n));
  EXPECT_NEAR(normal_squares / n, 1.0, 5.0 * std::sqrt(2.0 / n));
  for (const int count : counts) EXPECT_NEAR(count / static_cast<double>(n), 1.0 / 7.0, binomialTolerance(1.0 / 7.0, n));
  EXPECT_THROW(rng.below(0), std::invalid_argument);
}

TEST(World, DynamicCellsChangeAtTheirConfiguredRates) {
  World world(3, 1, 0.1);
  world.setDynamic(0, 0, core::TransitionParams{0.05, 0.2}, false);
  world.setStatic(1, 0, true);
  world.setScheduled(2, 0, core::TransitionParams{0.3, 0.3}, true);
  Rng rng(1);
  double from_free = 0;
  double free_to_occ = 0;
  double from_occ = 0;
  double occ_to_free = 0;
  for (int t = 0; t < 200000; ++t) {
    const bool before = world.occupied(0, 0);
    world.step(rng);
    const bool after = world.occupied(0, 0);
    (before ? from_occ : from_free) += 1;
    if (!before && after) ++free_to_occ;
    if (before && !after) ++occ_to_free;
    ASSERT_TRUE(world.occupied(1, 0));  // static
    ASSERT_TRUE(world.occupied(2, 0));  // changed by events only
  }
  EXPECT_NEAR(free_to_occ / from_free, 0.05, binomialTolerance(0.05, from_free));
  EXPECT_NEAR(occ_to_free / from_occ, 0.2, binomialTolerance(0.2, from_occ));
  // The chain spends pi(occ) = 0.05 / 0.25 of the time occupied.
  EXPECT_NEAR(from_occ / 200000.0, 0.2, 0.01);
  EXPECT_EQ(world.dynamicCells(), std::vector<std::size_t>{0});
  EXPECT_TRUE(world.truth(1, 0).isStatic());
  EXPECT_DOUBLE_EQ(world.truth(2, 0).p_occ_given_free, 0.3);
}

TEST(World, RejectsBadInput) {
  EXPECT_THROW(World(0, 5, 0.1), std::invalid_argument);
  EXPECT_THROW(World(5, 5, 0.0), std::invalid_argument);
  World world(5, 5, 0.1);
  EXPECT_THROW(world.setStatic(5, 0, true), std::invalid_argument);
  EXPECT_THROW(world.setDynamic(0, 0, core::TransitionParams{1.5, 0.1}, true), std::invalid_argument);
  EXPECT_FALSE(world.occupied(-1, 0));  // outside is free
}

// Reference for castRay: walk the ray in tiny increments and report the first point inside
// an occupied cell through which the ray runs for at least a tenth of a cell (shorter
// chords are corner grazes, which pass).
double marchedEntry(const World& world, double x, double y, double angle, double max_range) {
  const double step = 1e-5;
  const auto cell_at = [&](double t) {
    return core::CellXY{static_cast<std::int32_t>(std::floor((x + t * std::cos(angle)) / world.resolution())),
                  static_cast<std::int32_t>(std::floor((y + t * std::sin(angle)) / world.resolution()))};
  };
  for (double t = 0.0; t < max_range; t += step) {
    const core::CellXY cell = cell_at(t);
    if (!world.occupied(cell.x, cell.y)) continue;
    double leave = t;
    while (cell_at(leave) == cell) leave += step;
    if (leave - t >= 0.1 * world.resolution()) return t;
    t = leave - step;
  }
  return std::numeric_limits<double>::infinity();
}

TEST(CastRay, MatchesMarchingTheRay) {
  World world(20, 20, 0.1);
  Rng layout(3);
  for (int i = 0; i < 40; ++i) {
    world.setStatic(static_cast<std::int32_t>(layout.below(20)), static_cast<std::int32_t>(layout.below(20)), true);
  }
  world.setStatic(10, 10, false);
  Rng rng(4);
  for (int i = 0; i < 300; ++i) {
    const double angle = 2.0 * kPi * rng.uniform();
    const RayHit hit = castRay(world, 1.05, 1.05, angle, 1.5);
    const double reference = marchedEntry(world, 1.05, 1.05, angle, 1.5);
    if (std::isinf(reference)) {
      EXPECT_TRUE(std::isinf(hit.entry_m)) << "angle " << angle;
    } else {
      ASSERT_NEAR(hit.entry_m, reference, 2e-5) << "angle " << angle;
      // The exit is where the marching leaves that cell.
      const double mid = 0.5 * (hit.entry_m + hit.exit_m);
      EXPECT_GT(hit.exit_m, hit.entry_m);
      EXPECT_TRUE(world.occupied(static_cast<std::int32_t>(std::floor((1.05 + mid * std::cos(angle)) / 0.1)),
                                 static_cast<std::int32_t>(std::floor((1.05 + mid * std::sin(angle)) / 0.1))));
    }
  }
}

TEST(CastRay, ExactCasesAndEdges) {
  World world(10, 10, 0.1);
  world.setStatic(5, 2, true);
  // Along +x from the middle of cell (1, 2): enters cell 5 at x = 0.5, leaves at 0.6.
  RayHit hit = castRay(world, 0.15, 0.25, 0.0, 5.0);
  EXPECT_NEAR(hit.entry_m, 0.35, 1e-12);
  EXPECT_NEAR(hit.exit_m, 0.45, 1e-12);
  // Along -x from the other side.
  hit = castRay(world, 0.95, 0.25, kPi, 5.0);
  EXPECT_NEAR(hit.entry_m, 0.35, 1e-12);
  // Beyond max range, or leaving the world without meeting anything: +inf.
  EXPECT_TRUE(std::isinf(castRay(world, 0.15, 0.25, 0.0, 0.3).entry_m));
  EXPECT_TRUE(std::isinf(castRay(world, 0.15, 0.25, kPi / 2, 50.0).entry_m));
  // Starting inside an occupied cell.
  EXPECT_EQ(castRay(world, 0.55, 0.25, 1.0, 5.0).entry_m, 0.0);
  // Exactly through a corner of an occupied cell: it passes, and returns from the next
  // occupied cell along the diagonal.
  World corners(5, 5, 1.0);
  corners.setStatic(0, 1, true);
  corners.setStatic(2, 2, true);
  hit = castRay(corners, 0.5, 0.5, kPi / 4, 10.0);
  EXPECT_NEAR(hit.entry_m, 1.5 * std::sqrt(2.0), 1e-9);
  EXPECT_NEAR(hit.exit_m, 2.5 * std::sqrt(2.0), 1e-9);
}

TEST(SimulateScan, ReadsChordMiddlesWithNoiseDropoutsAndNoReturns) {
  World world(40, 40, 0.1);
  for (std::int32_t y = 0; y < 40; ++y) world.setStatic(30, y, true);  // a wall at x = 3.0 .. 3.1
  LaserConfig laser;
  laser.beams = 1;
  laser.angle_min_rad = 0.0;
  laser.range_max_m = 8.0;
  laser.noise_sigma_m = 0.01;
  laser.dropout_probability = 0.1;
  Rng rng(5);
  const core::Pose2D pose{1.0, 2.05, 0.0};
  const int n = 20000;
  double sum = 0.0;
  double squares = 0.0;
  int readings = 0;
  int dropouts = 0;
  for (int i = 0; i < n; ++i) {
    const core::Scan scan = simulateScan(world, pose, laser, 1.0, rng);
    ASSERT_EQ(scan.ranges_m.size(), 1U);
    const float r = scan.ranges_m[0];
    if (std::isnan(r)) {
      ++dropouts;
      continue;
    }
    ++readings;
    sum += r;
    squares += (r - 2.05) * (r - 2.05);
  }
  EXPECT_NEAR(dropouts / static_cast<double>(n), 0.1, binomialTolerance(0.1, n));
  EXPECT_NEAR(sum / readings, 2.05, 5.0 * 0.01 / std::sqrt(readings));  // the middle of the wall cell
  EXPECT_NEAR(std::sqrt(squares / readings), 0.01, 0.0005);

  // Looking away from the wall: no return reads +inf; the scan carries the laser's geometry.
  laser.dropout_probability = 0.0;
  const core::Scan away = simulateScan(world, core::Pose2D{1.0, 2.05, kPi}, laser, 3.5, rng);
  EXPECT_TRUE(std::isinf(away.ranges_m[0]));
  EXPECT_EQ(away.stamp_s, 3.5);
  EXPECT_EQ(away.range_max_m, 8.0);
}

TEST(SimulateScan, DarkBeamsReadNothingAndDrawNothing) {
  World world(40, 40, 0.1);
  for (std::int32_t y = 0; y < 40; ++y) world.setStatic(30, y, true);
  LaserConfig laser;
  laser.beams = 5;
  laser.angle_min_rad = -kPi / 2;
  laser.angle_increment_rad = kPi / 4;
  laser.dropout_probability = 0.0;
  const core::Pose2D pose{1.0, 2.05, 0.0};
  // Listing every beam is the same sensor as listing none: the same readings from the same
  // noise stream.
  Rng all_rng(9);
  Rng listed_rng(9);
  LaserConfig listed = laser;
  listed.active_beams = {0, 1, 2, 3, 4};
  const core::Scan all = simulateScan(world, pose, laser, 1.0, all_rng);
  const core::Scan same = simulateScan(world, pose, listed, 1.0, listed_rng);
  EXPECT_EQ(all.ranges_m, same.ranges_m);
  // The middle beam dark: NaN; the beams before it read as before.
  Rng dark_rng(9);
  listed.active_beams = {0, 1, 3, 4};
  const core::Scan dark = simulateScan(world, pose, listed, 1.0, dark_rng);
  ASSERT_EQ(dark.ranges_m.size(), 5U);
  EXPECT_TRUE(std::isnan(dark.ranges_m[2]));
  EXPECT_EQ(dark.ranges_m[0], all.ranges_m[0]);
  EXPECT_EQ(dark.ranges_m[1], all.ranges_m[1]);
  EXPECT_TRUE(std::isfinite(all.ranges_m[2]));  // the wall ahead: the dark beam would have read it
  for (const std::vector<int>& bad : {std::vector<int>{5}, std::vector<int>{-1}, std::vector<int>{1, 1},
                                      std::vector<int>{3, 1}}) {
    listed.active_beams = bad;
    EXPECT_THROW(listed.validate(), std::invalid_argument);
  }
}

TEST(LoopPath, DrivesTheLoopAtItsSpeed) {
  const LoopPath path({{0.0, 0.0}, {2.0, 0.0}, {2.0, 1.0}}, 0.5);
  EXPECT_NEAR(path.lengthM(), 3.0 + std::sqrt(5.0), 1e-12);
  core::Pose2D p = path.poseAt(1.0);
  EXPECT_NEAR(p.x_m, 0.5, 1e-12);
  EXPECT_NEAR(p.y_m, 0.0, 1e-12);
  EXPECT_NEAR(p.yaw_rad, 0.0, 1e-12);
  p = path.poseAt(5.0);  // 2.5 m: half way up the second segment
  EXPECT_NEAR(p.x_m, 2.0, 1e-12);
  EXPECT_NEAR(p.y_m, 0.5, 1e-12);
  EXPECT_NEAR(p.yaw_rad, kPi / 2, 1e-12);
  const core::Pose2D wrapped = path.poseAt(1.0 + path.lengthM() / 0.5);
  EXPECT_NEAR(wrapped.x_m, 0.5, 1e-9);
  EXPECT_THROW(LoopPath({{0.0, 0.0}}, 1.0), std::invalid_argument);
  EXPECT_THROW(LoopPath({{0.0, 0.0}, {1.0, 0.0}}, 0.0), std::invalid_argument);
}

TEST(Compose, MountsTheLaserOnTheRobot) {
  const core::Pose2D laser = core::composePose(core::Pose2D{1.0, 2.0, kPi / 2}, core::Pose2D{0.1, 0.0, 0.0});
  EXPECT_NEAR(laser.x_m, 1.0, 1e-12);
  EXPECT_NEAR(laser.y_m, 2.1, 1e-12);
  EXPECT_NEAR(laser.yaw_rad, kPi / 2, 1e-12);
}

TEST(Scenarios, NamesAndValidation) {
  for (const std::string& name : scenarioNames()) EXPECT_NO_THROW(scenarioConfig(name).validate()) << name;
  try {
    scenarioConfig("nope");
    FAIL() << "no exception";
  } catch (const std::invalid_argument& error) {
    EXPECT_NE(std::string(error.what()).find("dynamic_5_5"), std::string::npos);
  }
  ScenarioConfig bad = scenarioConfig("dynamic_5_5");
  bad.change_probability = 1.5;
  EXPECT_THROW(Simulation(bad, 1, 1), std::invalid_argument);
  for (const std::int64_t redraw : {std::int64_t{0}, std::int64_t{-2}, std::int64_t{1000}}) {
    ScenarioConfig never = scenarioConfig("redraw_100");
    never.redraw_at_step = redraw;  // would silently never re-draw
    EXPECT_THROW(never.validate(), std::invalid_argument) << redraw;
  }
}

// Cells whose truth says they are dynamic, and the empirical change rates over a run.
TEST(Scenarios, RandomDynamicHasItsFractionAndRates) {
  for (const std::string& name : {std::string("dynamic_5_5"), std::string("dynamic_25_25")}) {
    const ScenarioConfig config = scenarioConfig(name);
    Simulation simulation(config, 11, 12);
    const World& world = simulation.world();
    const std::vector<std::size_t> dynamic = world.dynamicCells();
    std::size_t candidates = 0;  // neither a wall nor the robot's lane: free or dynamic
    for (std::size_t i = 0; i < world.occupancy().size(); ++i) {
      const core::CellXY c = world.cellOf(i);
      const bool wall = !world.isDynamic(c.x, c.y) && world.occupied(c.x, c.y);
      if (!wall) ++candidates;
    }
    // The lane cells are free candidates too: the fraction of all non-wall cells is a
    // little below the configured fraction of the candidates.
    const double fraction = static_cast<double>(dynamic.size()) / static_cast<double>(candidates);
    EXPECT_GT(fraction, 0.75 * config.dynamic_fraction) << name;
    EXPECT_LE(fraction, config.dynamic_fraction) << name;

    // The robot drives its loop on free cells only (checked below, step by step).
    std::vector<std::uint8_t> before = world.occupancy();
    double changes = 0.0;
    double trials = 0.0;
    for (int t = 0; t < 400; ++t) {
      const core::Pose2D robot = simulation.robotPose();
      ASSERT_FALSE(world.occupied(static_cast<std::int32_t>(robot.x_m / config.resolution_m),
                                  static_cast<std::int32_t>(robot.y_m / config.resolution_m)))
          << name << " step " << t;
      simulation.advance();
      const std::vector<std::uint8_t>& after = world.occupancy();
      for (std::size_t i = 0; i < after.size(); ++i) {
        const core::CellXY c = world.cellOf(i);
        if (world.isDynamic(c.x, c.y)) {
          trials += 1.0;
          changes += before[i] != after[i];
        } else {
          ASSERT_EQ(before[i], after[i]) << "a static cell changed";
        }
      }
      before = after;
    }
    EXPECT_NEAR(changes / trials, config.change_probability, binomialTolerance(config.change_probability, trials))
        << name;
  }
}

TEST(Scenarios, RedrawReplacesTheDynamicCellsAtItsStep) {
  const ScenarioConfig config = scenarioConfig("redraw_100");
  Simulation simulation(config, 21, 22);
  ScenarioConfig no_redraw = config;
  no_redraw.redraw_at_step = -1;
  Simulation training(no_redraw, 21, 99);  // same place, another day
  const std::vector<std::size_t> first = simulation.world().dynamicCells();
  EXPECT_EQ(training.world().dynamicCells(), first);
  for (int t = 0; t < 99; ++t) simulation.advance();
  EXPECT_EQ(simulation.world().dynamicCells(), first);
  simulation.advance();  // step 100
  const std::vector<std::size_t> second = simulation.world().dynamicCells();
  EXPECT_EQ(second.size(), first.size());
  std::size_t kept = 0;
  for (const std::size_t i : second) kept += std::count(first.begin(), first.end(), i);
  EXPECT_LT(kept, first.size() / 4);  // a fresh random set: few cells in common
  for (int t = 0; t < 100; ++t) training.advance();
  EXPECT_EQ(training.world().dynamicCells(), first);
}

TEST(Scenarios, ParkingLotChangesOnlyOnTheHourAtItsRates) {
  ScenarioConfig config = scenarioConfig("parking_lot");
  config.steps_per_hour = 2;  // many hours quickly
  Simulation simulation(config, 31, 32);
  const World& world = simulation.world();
  const std::vector<std::uint8_t> start = world.occupancy();
  double arrivals = 0, empty = 0, departures = 0, parked = 0;
  std::vector<std::uint8_t> before = start;
  for (int t = 1; t <= 4000; ++t) {
    simulation.advance();
    const std::vector<std::uint8_t>& after = world.occupancy();
    if (t % config.steps_per_hour != 0) {
      ASSERT_EQ(after, before) << "changed within an hour at step " << t;
      continue;
    }
    // Bays by their first cell: bay columns start at x = 2, 12, ..., rows at y = 2 and 34.
    for (const std::int32_t y : {2, 34}) {
      for (std::int32_t x = 2; x < 60; x += 10) {
        const bool was = before[world.index(x, y)] != 0;
        const bool is = after[world.index(x, y)] != 0;
        // A whole car comes or goes.
        for (std::int32_t dy = 0; dy < 18; ++dy) {
          for (std::int32_t dx = 0; dx < 8; ++dx) ASSERT_EQ(after[world.index(x + dx, y + dy)], is);
        }
        if (was) {
          ++parked;
          departures += !is;
        } else {
          ++empty;
          arrivals += is;
        }
      }
    }
    before = after;
  }
  EXPECT_NEAR(arrivals / empty, config.p_arrive_per_hour, binomialTolerance(config.p_arrive_per_hour, empty));
  EXPECT_NEAR(departures / parked, config.p_leave_per_hour, binomialTolerance(config.p_leave_per_hour, parked));
  // The oracle's rates: the hourly probabilities spread over the hour's steps.
  EXPECT_DOUBLE_EQ(world.truth(2, 2).p_occ_given_free, config.p_arrive_per_hour / config.steps_per_hour);
}

// Shortest 4-connected path length on the free cells, by breadth-first search.
int shortestPath(const World& world, core::CellXY from, core::CellXY to, bool door_open, core::CellXY door) {
  std::vector<int> distance(world.occupancy().size(), -1);
  std::deque<core::CellXY> queue{from};
  distance[world.index(from.x, from.y)] = 0;
  while (!queue.empty()) {
    const core::CellXY c = queue.front();
    queue.pop_front();
    if (c == to) return distance[world.index(c.x, c.y)];
    for (const auto& [dx, dy] : {std::pair{1, 0}, std::pair{-1, 0}, std::pair{0, 1}, std::pair{0, -1}}) {
      const core::CellXY n{c.x + dx, c.y + dy};
      if (!world.inside(n.x, n.y) || distance[world.index(n.x, n.y)] >= 0) continue;
      const bool blocked = n == door ? !door_open : world.occupied(n.x, n.y);
      if (blocked) continue;
      distance[world.index(n.x, n.y)] = distance[world.index(c.x, c.y)] + 1;
      queue.push_back(n);
    }
  }
  return -1;
}

TEST(Scenarios, DoorLayoutAndExplorationRoute) {
  const ScenarioConfig config = scenarioConfig("door");
  Simulation simulation(config, 41, 42);
  const DoorLayout& layout = simulation.doorLayout();
  const World& world = simulation.world();
  EXPECT_EQ(shortestPath(world, layout.a, layout.b, true, layout.door), layout.short_path_cells);
  EXPECT_EQ(shortestPath(world, layout.a, layout.b, false, layout.door), layout.long_path_cells);
  EXPECT_LT(layout.short_path_cells, layout.long_path_cells);
  EXPECT_TRUE(world.isDynamic(layout.door.x, layout.door.y));
  EXPECT_DOUBLE_EQ(world.truth(layout.door.x, layout.door.y).p_occ_given_free, config.door_change_probability);
  EXPECT_EQ(world.dynamicCells().size(), 1U);
  // From A the door is out of the laser's range.
  const double gap = (layout.door.x - layout.a.x - 0.5) * config.resolution_m;
  EXPECT_GT(gap, config.laser.range_max_m);
  // The exploration loop never enters the door cell, and sees it from both sides.
  bool near_west = false;
  bool near_east = false;
  for (int t = 0; t < 400; ++t) {
    const core::Pose2D p = simulation.robotPose();
    const core::CellXY c{static_cast<std::int32_t>(std::floor(p.x_m / config.resolution_m)),
                   static_cast<std::int32_t>(std::floor(p.y_m / config.resolution_m))};
    ASSERT_NE(c, layout.door);
    ASSERT_FALSE(world.occupied(c.x, c.y) && c != layout.door);
    near_west = near_west || (c.y == layout.door.y && c.x == layout.door.x - 1);
    near_east = near_east || (c.y == layout.door.y && c.x == layout.door.x + 1);
    simulation.advance();
  }
  EXPECT_TRUE(near_west);
  EXPECT_TRUE(near_east);
  EXPECT_THROW(Simulation(scenarioConfig("dynamic_5_5"), 1, 1).doorLayout(), std::logic_error);
}

// Li, Barão & Rato's simulation (Sec. IV): four squares holding their state for dt/3, 2 dt,
// 3 dt and 7 dt, whose truth is the Markov rate 1 / hold; static walls on the left;
// everything else static and free. dt is not the robot's loop: the holds are incommensurate
// with it.
TEST(Scenarios, MrfSquaresHoldTheirStatesForTheirHoldTimes) {
  const ScenarioConfig config = scenarioConfig("mrf_squares");
  Simulation simulation(config, 71, 72);
  const MrfSquaresLayout& layout = simulation.mrfSquaresLayout();
  const World& world = simulation.world();
  const std::int64_t loop = layout.loop_steps;
  const std::int64_t dt = layout.delta_t_steps;
  EXPECT_EQ(loop, 24);
  EXPECT_EQ(dt, 21);
  EXPECT_EQ(config.square_hold_steps, (std::array<std::int64_t, 4>{dt / 3, 2 * dt, 3 * dt, 7 * dt}));
  EXPECT_EQ(dt / 3 * 3, dt);
  EXPECT_EQ(config.steps, 20 * loop);
  // A square's states repeat every 2 hold steps, the robot's visits every loop: it meets a
  // square at the same point of its cycle again after lcm(2 hold, loop) / loop loops. At
  // least 7 for every square (with dt = loop: 2 for the fastest, met only in mirrored
  // visits), and no square within a run for the slow two.
  std::array<std::int64_t, 4> repeat_loops{};
  for (std::size_t k = 0; k < 4; ++k) {
    const std::int64_t period = 2 * config.square_hold_steps[k];
    repeat_loops[k] = period / std::gcd(period, loop);  // lcm(period, loop) / loop
    EXPECT_GE(repeat_loops[k], 7) << k;
  }
  EXPECT_EQ(repeat_loops, (std::array<std::int64_t, 4>{7, 7, 21, 49}));
  EXPECT_GT(repeat_loops[2], config.steps / loop);
  const auto square_of = [&](std::int32_t x, std::int32_t y) {
    for (std::size_t k = 0; k < layout.square_corner.size(); ++k) {
      const core::CellXY c = layout.square_corner[k];
      if (x >= c.x && y >= c.y && x < c.x + layout.square_side_cells && y < c.y + layout.square_side_cells) {
        return static_cast<int>(k);
      }
    }
    return -1;
  };
  std::int32_t leftmost_square = world.width();
  for (const core::CellXY c : layout.square_corner) leftmost_square = std::min(leftmost_square, c.x);
  std::size_t walls = 0;
  for (std::int32_t y = 0; y < world.height(); ++y) {
    for (std::int32_t x = 0; x < world.width(); ++x) {
      const int k = square_of(x, y);
      if (k >= 0) {
        const double rate = 1.0 / static_cast<double>(config.square_hold_steps[static_cast<std::size_t>(k)]);
        EXPECT_DOUBLE_EQ(world.truth(x, y).p_occ_given_free, rate);
        EXPECT_DOUBLE_EQ(world.truth(x, y).p_free_given_occ, rate);
      } else {
        ASSERT_TRUE(world.truth(x, y).isStatic()) << x << ", " << y;
        if (world.occupied(x, y)) {
          ++walls;
          EXPECT_LT(x, leftmost_square);  // the walls are on the left
        }
      }
      EXPECT_FALSE(world.isDynamic(x, y));  // changed by the schedule only
    }
  }
  EXPECT_GT(walls, 20U);

  // Every hold between two toggles lasts exactly its time; the first (the run starts inside a
  // hold) at most that; all cells of a square change together; nothing else changes.
  std::array<std::vector<std::int64_t>, 4> toggles;
  std::vector<std::uint8_t> before = world.occupancy();
  for (std::int64_t t = 1; t <= config.steps; ++t) {
    simulation.advance();
    const std::vector<std::uint8_t>& after = world.occupancy();
    std::array<int, 4> changed{};
    for (std::size_t i = 0; i < after.size(); ++i) {
      if (after[i] == before[i]) continue;
      const core::CellXY c = world.cellOf(i);
      const int k = square_of(c.x, c.y);
      ASSERT_GE(k, 0) << "cell " << c.x << ", " << c.y << " changed at step " << t;
      ++changed[static_cast<std::size_t>(k)];
    }
    for (std::size_t k = 0; k < 4; ++k) {
      if (changed[k] == 0) continue;
      EXPECT_EQ(changed[k], layout.square_side_cells * layout.square_side_cells);
      toggles[k].push_back(t);
    }
    before = after;
  }
  for (std::size_t k = 0; k < 4; ++k) {
    const std::int64_t hold = config.square_hold_steps[k];
    ASSERT_GE(toggles[k].size(), 2U) << k;
    EXPECT_LE(toggles[k].front(), hold) << k;
    for (std::size_t j = 1; j < toggles[k].size(); ++j) EXPECT_EQ(toggles[k][j] - toggles[k][j - 1], hold) << k;
    EXPECT_GT(toggles[k].back() + hold, config.steps) << k;  // none missed at the end
  }
  EXPECT_THROW(Simulation(scenarioConfig("door"), 1, 1).mrfSquaresLayout(), std::logic_error);
}

// Four beams at -pi/2, -pi/4, pi/4, pi/2 from the heading, 8 cells long; a robot at 3 cells
// per step whose pose is off its loop by the configured noise, never inside an object.
TEST(Scenarios, MrfSquaresRobotAndBeams) {
  const ScenarioConfig config = scenarioConfig("mrf_squares");
  EXPECT_DOUBLE_EQ(config.laser.range_max_m, 8 * config.resolution_m);
  EXPECT_DOUBLE_EQ(config.robot_speed_m_per_step, 3 * config.resolution_m);
  Simulation simulation(config, 81, 82);
  const std::int64_t dt = simulation.mrfSquaresLayout().loop_steps;  // the loop
  std::vector<core::Pose2D> poses;
  std::array<int, 5> readings{};
  for (std::int64_t t = 0; t < config.steps; ++t) {
    const core::Pose2D robot = simulation.robotPose();
    poses.push_back(robot);
    ASSERT_FALSE(simulation.world().occupied(static_cast<std::int32_t>(std::floor(robot.x_m / config.resolution_m)),
                                             static_cast<std::int32_t>(std::floor(robot.y_m / config.resolution_m))))
        << "step " << t;
    const core::Scan scan = simulation.scan();
    EXPECT_EQ(scan.laser_pose.x_m, robot.x_m);
    EXPECT_EQ(scan.laser_pose.yaw_rad, robot.yaw_rad);
    ASSERT_EQ(scan.ranges_m.size(), 5U);
    for (std::size_t i = 0; i < 5; ++i) {
      if (std::isnan(scan.ranges_m[i])) continue;
      ++readings[i];
      EXPECT_TRUE(std::isinf(scan.ranges_m[i]) || scan.ranges_m[i] < 8 * config.resolution_m);
    }
    // A beam's reading is where castRay meets the world in its direction (up to the noise).
    for (const std::size_t i : {std::size_t{0}, std::size_t{1}, std::size_t{3}, std::size_t{4}}) {
      const double angle = robot.yaw_rad + scan.angle_min_rad + static_cast<double>(i) * scan.angle_increment_rad;
      const RayHit hit = castRay(simulation.world(), robot.x_m, robot.y_m, angle, scan.range_max_m);
      if (std::isfinite(hit.entry_m) && std::isfinite(scan.ranges_m[i])) {
        EXPECT_NEAR(scan.ranges_m[i], 0.5 * (hit.entry_m + hit.exit_m), 6.0 * config.laser.noise_sigma_m);
      }
    }
    simulation.advance();
  }
  EXPECT_NEAR(simulation.scan().angle_min_rad, -kPi / 2, 1e-12);
  EXPECT_NEAR(simulation.scan().angle_increment_rad, kPi / 4, 1e-12);
  // The beam straight ahead never reads; the four others always do (no dropouts).
  EXPECT_EQ(readings, (std::array<int, 5>{static_cast<int>(config.steps), static_cast<int>(config.steps), 0,
                                          static_cast<int>(config.steps), static_cast<int>(config.steps)}));
  // One loop later the robot is where it was but for the noise of the two steps: differences
  // of sigma * sqrt(2) per axis, no drift.
  double dx = 0.0, dx2 = 0.0, dyaw2 = 0.0;
  double n = 0.0;
  for (std::size_t t = 0; t + static_cast<std::size_t>(dt) < poses.size(); ++t) {
    const core::Pose2D& a = poses[t];
    const core::Pose2D& b = poses[t + static_cast<std::size_t>(dt)];
    dx += b.x_m - a.x_m;
    dx2 += (b.x_m - a.x_m) * (b.x_m - a.x_m) + (b.y_m - a.y_m) * (b.y_m - a.y_m);
    dyaw2 += (b.yaw_rad - a.yaw_rad) * (b.yaw_rad - a.yaw_rad);
    n += 1.0;
  }
  const double sigma = config.path_noise_sigma_m;
  EXPECT_NEAR(dx / n, 0.0, 5.0 * sigma * std::sqrt(2.0 / n));
  EXPECT_NEAR(std::sqrt(dx2 / (2.0 * n)), sigma * std::sqrt(2.0), 0.1 * sigma);
  EXPECT_NEAR(std::sqrt(dyaw2 / n), config.path_noise_sigma_rad * std::sqrt(2.0), 0.1 * config.path_noise_sigma_rad);
  // Half a loop later it is elsewhere: the loop is dt steps long.
  EXPECT_GT(std::hypot(poses[static_cast<std::size_t>(dt / 2)].x_m - poses[0].x_m,
                       poses[static_cast<std::size_t>(dt / 2)].y_m - poses[0].y_m),
            10 * config.resolution_m);
  // The noise comes from the run seed: the same run again is the same, another run differs.
  Simulation again(config, 81, 82);
  Simulation other(config, 81, 83);
  EXPECT_EQ(again.robotPose().x_m, poses[0].x_m);
  EXPECT_NE(other.robotPose().x_m, poses[0].x_m);
}

// The sensor model each scenario maps with is no more certain than its laser: measured
// per-beam hit rates on occupied cells at least p_hit_given_occ, on free cells at most
// p_hit_given_free. Pooled over four runs: in mrf_squares few occupied cells are seen (its
// walls and the squares' faces), and one run's rate on them varies by run (0.74 to 0.89 over
// 40 runs of 200 steps, 0.83 pooled, against its 0.8).
TEST(Scenarios, SensorModelIsNoMoreCertainThanTheLaser) {
  for (const std::string& name : scenarioNames()) {
    const ScenarioConfig config = scenarioConfig(name);
    double hits[2] = {0, 0};
    double readings[2] = {0, 0};
    for (std::uint64_t run = 0; run < 4; ++run) {
      Simulation simulation(config, 51 + 2 * run, 52 + 2 * run);
      core::MapperConfig mapper_config;
      mapper_config.resolution_m = config.resolution_m;
      mapper_config.fixed_bounds = true;
      mapper_config.width_m = config.width_cells * config.resolution_m;
      mapper_config.height_m = config.height_cells * config.resolution_m;
      core::Mapper mapper(mapper_config);
      core::SequenceBuilder recorder;
      mapper.recordObservations(&recorder);
      std::vector<std::vector<std::uint8_t>> truth;
      for (int t = 0; t < 200; ++t) {
        for (int k = 0; k < config.scans_per_step; ++k) mapper.integrate(simulation.scan(k));
        truth.push_back(simulation.world().occupancy());
        simulation.advance();
      }
      mapper.finishStep();
      const core::ObservationSequences sequences = recorder.build();
      for (std::size_t i = 0; i < sequences.cellCount(); ++i) {
        const core::CellXY c = sequences.cell(i);
        for (const core::StepObservation* o = sequences.begin(i); o != sequences.end(i); ++o) {
          const int occupied = truth[static_cast<std::size_t>(o->step)][simulation.world().index(c.x, c.y)];
          hits[occupied] += o->hits;
          readings[occupied] += o->hits + o->misses;
        }
      }
    }
    EXPECT_GE(hits[1] / readings[1], config.p_hit_given_occ) << name;
    EXPECT_LE(hits[0] / readings[0], config.p_hit_given_free) << name;
  }
}

TEST(Simulation, ScanStampsFallInTheirStepAndRunsReproduce) {
  ScenarioConfig config = scenarioConfig("dynamic_5_5");
  config.scans_per_step = 4;
  Simulation a(config, 61, 62);
  Simulation b(config, 61, 62);
  for (int t = 0; t < 5; ++t) {
    for (int k = 0; k < 4; ++k) {
      const core::Scan sa = a.scan(k);
      const core::Scan sb = b.scan(k);
      EXPECT_GT(sa.stamp_s, t * config.time_step_s);
      EXPECT_LT(sa.stamp_s, (t + 1) * config.time_step_s);
      ASSERT_EQ(sa.ranges_m.size(), sb.ranges_m.size());
      for (std::size_t i = 0; i < sa.ranges_m.size(); ++i) {
        EXPECT_TRUE(sa.ranges_m[i] == sb.ranges_m[i] || (std::isnan(sa.ranges_m[i]) && std::isnan(sb.ranges_m[i])));
      }
    }
    a.advance();
    b.advance();
  }
  EXPECT_EQ(a.world().occupancy(), b.world().occupancy());
  EXPECT_THROW(a.scan(4), std::invalid_argument);
}

// The dividers scenario (DividersLayout): dividers move only at multiples of the period, each
// toggling with the documented probability, at least one passage always open; people move one
// cell per step and never overlap structure or each other; structure and people are told
// apart; the same seeds give the same run.
TEST(Scenarios, DividersMoveAtTheDocumentedRateAndOnePassageIsAlwaysOpen) {
  ScenarioConfig config = scenarioConfig("dividers");
  config.divider_period_steps = 5;
  config.people = 0;
  Simulation simulation(config, 3, 4);
  const DividersLayout& layout = simulation.dividersLayout();
  ASSERT_EQ(layout.passage_min_y.size(), 3U);
  double toggles = 0.0;
  double chances = 0.0;
  double forced = 0.0;  // moves that left the same two passages closed
  std::vector<std::uint8_t> before = layout.closed;
  for (int t = 1; t <= 20000; ++t) {
    simulation.advance();
    const std::vector<std::uint8_t>& now = layout.closed;
    ASSERT_LT(std::count(now.begin(), now.end(), 1), 3) << "step " << t;
    for (std::size_t p = 0; p < now.size(); ++p) {
      // The world agrees with the layout, on every cell of the divider.
      for (std::int32_t y = layout.passage_min_y[p]; y < layout.passage_min_y[p] + layout.passage_height; ++y) {
        ASSERT_EQ(simulation.world().occupied(layout.wall_x, y), now[p] != 0);
        ASSERT_EQ(simulation.isStructure(layout.wall_x, y), now[p] != 0);
      }
    }
    if (t % config.divider_period_steps != 0) {
      ASSERT_EQ(now, before) << "a divider moved between periods, step " << t;
      continue;
    }
    // The rule that keeps a passage open only ever keeps an open divider open: a closed
    // divider opens with exactly the toggle probability.
    for (std::size_t p = 0; p < now.size(); ++p) {
      if (before[p] == 0) continue;
      toggles += now[p] == 0 ? 1.0 : 0.0;
      chances += 1.0;
    }
    forced += std::count(before.begin(), before.end(), 1) == 2 && std::count(now.begin(), now.end(), 1) == 2 ? 1.0 : 0.0;
    before = now;
  }
  ASSERT_GT(chances, 3000.0);
  const double p = config.divider_toggle_probability;
  EXPECT_NEAR(toggles / chances, p, binomialTolerance(p, chances));
  // Two closed stay closed and the open one closes: the rule re-opened it (or it stayed open).
  EXPECT_GT(forced, 0.0);
}

TEST(Scenarios, DividersPeopleWalkOneCellPerStepAndNeverOverlapStructure) {
  ScenarioConfig config = scenarioConfig("dividers");
  config.divider_period_steps = 7;  // many divider moves, some of them onto people
  config.divider_toggle_probability = 0.5;
  config.people = 6;
  Simulation simulation(config, 5, 6);
  const DividersLayout& layout = simulation.dividersLayout();
  ASSERT_EQ(layout.people.size(), 6U);
  std::vector<core::CellXY> before = layout.people;
  double moves = 0.0;
  int crossings = 0;
  for (int t = 1; t <= 5000; ++t) {
    simulation.advance();
    const bool dividers_moved = t % config.divider_period_steps == 0;
    for (std::size_t i = 0; i < layout.people.size(); ++i) {
      const core::CellXY c = layout.people[i];
      ASSERT_TRUE(simulation.world().occupied(c.x, c.y));
      ASSERT_TRUE(simulation.isPerson(c.x, c.y));
      ASSERT_FALSE(simulation.isStructure(c.x, c.y));
      // Not on a wall cell nor a closed divider (the wall column only in an open passage).
      if (c.x == layout.wall_x) {
        const int p = layout.dividerAt(c.x, c.y);
        ASSERT_GE(p, 0);
        ASSERT_EQ(layout.closed[static_cast<std::size_t>(p)], 0);
      }
      ASSERT_TRUE(c.x > 0 && c.y > 0 && c.x < config.width_cells - 1 && c.y < config.height_cells - 1);
      for (std::size_t j = 0; j < i; ++j) ASSERT_FALSE(layout.people[j] == c);
      const int step = std::abs(c.x - before[i].x) + std::abs(c.y - before[i].y);
      if (!dividers_moved) {
        ASSERT_LE(step, 1) << "person " << i << " step " << t;
      }
      moves += step == 1 ? 1.0 : 0.0;
      if ((before[i].x < layout.wall_x) != (c.x < layout.wall_x) && c.x != layout.wall_x) ++crossings;
    }
    before = layout.people;
    // Every occupied cell is either structure or a person, never both.
    std::size_t people_cells = 0;
    for (std::int32_t y = 0; y < config.height_cells; ++y) {
      for (std::int32_t x = 0; x < config.width_cells; ++x) {
        ASSERT_EQ(simulation.world().occupied(x, y), simulation.isStructure(x, y) || simulation.isPerson(x, y));
        ASSERT_FALSE(simulation.isStructure(x, y) && simulation.isPerson(x, y));
        people_cells += simulation.isPerson(x, y) ? 1 : 0;
      }
    }
    ASSERT_EQ(people_cells, 6U);
  }
  // People are fast: they move on (almost) every step, and cross the wall now and then.
  EXPECT_GT(moves / (5000.0 * 6.0), 0.95);
  EXPECT_GT(crossings, 0);
}

TEST(Scenarios, DividersRunsReproducePerSeedAndPeopleHideFromTheLaserInTheirCell) {
  const ScenarioConfig config = scenarioConfig("dividers");
  Simulation a(config, 7, 8);
  Simulation b(config, 7, 8);
  Simulation c(config, 7, 9);
  bool differs = false;
  for (int t = 0; t < 2 * config.divider_period_steps + 10; ++t) {
    ASSERT_EQ(a.world().occupancy(), b.world().occupancy());
    ASSERT_EQ(a.dividersLayout().closed, b.dividersLayout().closed);
    differs = differs || a.world().occupancy() != c.world().occupancy();
    a.advance();
    b.advance();
    c.advance();
  }
  EXPECT_TRUE(differs);
  // A laser in a person's cell reads as if the cell were free (no range_min hits).
  const core::CellXY person = a.dividersLayout().people.front();
  const double r = config.resolution_m;
  const core::Scan scan = a.scanFrom(core::Pose2D{(person.x + 0.5) * r, (person.y + 0.5) * r, 0.0});
  int short_readings = 0;
  for (const float range : scan.ranges_m) short_readings += std::isfinite(range) && range < 0.5 * r ? 1 : 0;
  EXPECT_EQ(short_readings, 0);
  EXPECT_TRUE(a.world().occupied(person.x, person.y));  // restored after the scan
  // The robot's places face each other across the middle passage.
  const DividersLayout& layout = a.dividersLayout();
  EXPECT_EQ(layout.a.y, layout.b.y);
  EXPECT_EQ(layout.dividerAt(layout.wall_x, layout.a.y), 1);
  EXPECT_LT(layout.a.x, layout.wall_x);
  EXPECT_GT(layout.b.x, layout.wall_x);
  EXPECT_THROW(Simulation(scenarioConfig("door"), 1, 2).dividersLayout(), std::logic_error);
}

// ---- the sparse office (PatrolFloor::kSparseOffice) -----------------------------------------

// Few changing cells, each part with its kind's true rates, measured on a long run of the
// parts' chains.
TEST(Scenarios, SparseOfficeHasFewChangingCellsChangingAtTheirRates) {
  const ScenarioConfig config = scenarioConfig("sparse_office");
  EXPECT_EQ(config.resolution_m, 0.05);
  Simulation simulation(config, 71, 72);
  const World& world = simulation.world();
  const PatrolLayout& layout = simulation.patrolLayout();
  const std::map<std::string, core::TransitionParams> rates{
      {"door", {0.03, 0.03}}, {"cart", {0.01, 0.02}}, {"person", {0.15, 0.30}}};
  std::map<std::string, int> parts;
  std::size_t part_cells = 0;
  for (const PatrolLayout::Part& part : layout.parts) {
    ++parts[part.kind];
    part_cells += part.cells.size();
    for (const core::CellXY& c : part.cells) {
      ASSERT_EQ(world.truth(c.x, c.y).p_occ_given_free, rates.at(part.kind).p_occ_given_free) << part.kind;
      ASSERT_EQ(world.truth(c.x, c.y).p_free_given_occ, rates.at(part.kind).p_free_given_occ) << part.kind;
    }
  }
  EXPECT_EQ(parts, (std::map<std::string, int>{{"cart", 4}, {"door", 3}, {"person", 6}}));
  std::size_t changing = 0;
  for (std::int32_t y = 0; y < world.height(); ++y) {
    for (std::int32_t x = 0; x < world.width(); ++x) changing += world.truth(x, y).isStatic() ? 0 : 1;
  }
  EXPECT_EQ(changing, part_cells);  // no cell in two parts, no changing cell outside them
  EXPECT_LE(static_cast<double>(changing), 0.02 * world.width() * world.height());
  EXPECT_EQ(world.width() * config.resolution_m, 16.0);
  EXPECT_EQ(world.height() * config.resolution_m, 12.0);

  // Per kind, how often a part left each state in the step after being in it.
  std::map<std::string, std::array<double, 4>> counts;  // left free, free steps, left occupied, occupied steps
  std::vector<std::uint8_t> before(layout.parts.size());
  const auto state = [&](std::size_t k) {
    const core::CellXY c = layout.parts[k].cells.front();
    return world.occupied(c.x, c.y) ? 1 : 0;
  };
  for (std::size_t k = 0; k < layout.parts.size(); ++k) before[k] = state(k);
  for (int t = 0; t < 20000; ++t) {
    simulation.advance();
    for (std::size_t k = 0; k < layout.parts.size(); ++k) {
      const int now = state(k);
      for (const core::CellXY& c : layout.parts[k].cells) ASSERT_EQ(world.occupied(c.x, c.y) ? 1 : 0, now);
      std::array<double, 4>& n = counts[layout.parts[k].kind];
      const int from = before[k];
      n[from == 0 ? 1 : 3] += 1.0;
      if (now != from) n[from == 0 ? 0 : 2] += 1.0;
      before[k] = static_cast<std::uint8_t>(now);
    }
  }
  for (const auto& [kind, n] : counts) {
    const core::TransitionParams& truth = rates.at(kind);
    EXPECT_NEAR(n[0] / n[1], truth.p_occ_given_free, binomialTolerance(truth.p_occ_given_free, n[1])) << kind;
    EXPECT_NEAR(n[2] / n[3], truth.p_free_given_occ, binomialTolerance(truth.p_free_given_occ, n[3])) << kind;
  }
}

// The robot drives a 60 m loop (120 steps) clear of walls and parts, and its laser sees each
// part only a few steps of every loop: a step counts when a beam hits or crosses one of the
// part's cells (the mapper's observations).
TEST(Scenarios, SparseOfficeSeesEachPartAFewStepsPerLoop) {
  const ScenarioConfig config = scenarioConfig("sparse_office");
  Simulation simulation(config, 73, 74);
  const World& world = simulation.world();
  const PatrolLayout& layout = simulation.patrolLayout();
  const std::int64_t loop = 120;
  core::MapperConfig mapper_config;
  mapper_config.resolution_m = config.resolution_m;
  mapper_config.fixed_bounds = true;
  mapper_config.width_m = config.width_cells * config.resolution_m;
  mapper_config.height_m = config.height_cells * config.resolution_m;
  core::Mapper mapper(mapper_config);
  core::SequenceBuilder recorder;
  mapper.recordObservations(&recorder);
  const core::Pose2D start = simulation.robotPose();
  for (std::int64_t t = 0; t < 2 * loop; ++t) {
    for (int k = 0; k < config.scans_per_step; ++k) {
      const core::Pose2D robot = simulation.robotPose(k);
      ASSERT_FALSE(world.occupied(static_cast<std::int32_t>(robot.x_m / config.resolution_m),
                                  static_cast<std::int32_t>(robot.y_m / config.resolution_m)))
          << "step " << t;
      for (const PatrolLayout::Part& part : layout.parts) {
        for (const core::CellXY& c : part.cells) {
          const double dx = (c.x + 0.5) * config.resolution_m - robot.x_m;
          const double dy = (c.y + 0.5) * config.resolution_m - robot.y_m;
          ASSERT_GT(dx * dx + dy * dy, 0.5 * 0.5) << part.kind << " step " << t;
        }
      }
      mapper.integrate(simulation.scan(k));
    }
    simulation.advance();
    if (t + 1 == loop / 2) {  // half a loop from the start, across the office
      const core::Pose2D half = simulation.robotPose();
      EXPECT_GT(std::hypot(half.x_m - start.x_m, half.y_m - start.y_m), 5.0);
    }
  }
  EXPECT_NEAR(simulation.robotPose().x_m, start.x_m, 1e-9);  // two loops later, back at the start
  EXPECT_NEAR(simulation.robotPose().y_m, start.y_m, 1e-9);
  mapper.finishStep();
  const core::ObservationSequences sequences = recorder.build();
  std::map<std::size_t, std::size_t> sequence_of;  // world index -> the cell's sequence
  for (std::size_t i = 0; i < sequences.cellCount(); ++i) {
    sequence_of[world.index(sequences.cell(i).x, sequences.cell(i).y)] = i;
  }
  for (const PatrolLayout::Part& part : layout.parts) {
    std::array<std::set<std::int64_t>, 2> in_view;  // per loop, the steps
    std::size_t seen_cells = 0;
    for (const core::CellXY& c : part.cells) {
      const auto found = sequence_of.find(world.index(c.x, c.y));
      if (found == sequence_of.end()) continue;
      ++seen_cells;
      for (const core::StepObservation* o = sequences.begin(found->second); o != sequences.end(found->second); ++o) {
        in_view[static_cast<std::size_t>(o->step / loop)].insert(o->step);
      }
    }
    EXPECT_EQ(seen_cells, part.cells.size()) << part.kind;  // two loops show all of a part
    for (std::size_t l = 0; l < in_view.size(); ++l) {
      EXPECT_GE(in_view[l].size(), 3U) << part.kind << " loop " << l;
      EXPECT_LE(in_view[l].size(), 12U) << part.kind << " loop " << l;  // a tenth of the loop
    }
  }
}

TEST(Scenarios, SparseOfficeRunsReproducePerSeed) {
  const ScenarioConfig config = scenarioConfig("sparse_office");
  Simulation a(config, 75, 76);
  Simulation b(config, 75, 76);
  Simulation c(config, 75, 77);
  Simulation other_place(config, 99, 76);
  ASSERT_EQ(a.patrolLayout().parts.size(), c.patrolLayout().parts.size());
  for (std::size_t k = 0; k < a.patrolLayout().parts.size(); ++k) {
    EXPECT_EQ(a.patrolLayout().parts[k].cells.size(), other_place.patrolLayout().parts[k].cells.size());
  }
  bool differs = false;
  for (int t = 0; t < 150; ++t) {
    ASSERT_EQ(a.world().occupancy(), b.world().occupancy()) << t;
    const core::Scan sa = a.scan(t % config.scans_per_step);
    const core::Scan sb = b.scan(t % config.scans_per_step);
    ASSERT_EQ(sa.ranges_m.size(), sb.ranges_m.size());
    for (std::size_t i = 0; i < sa.ranges_m.size(); ++i) {
      ASSERT_TRUE(sa.ranges_m[i] == sb.ranges_m[i] || (std::isnan(sa.ranges_m[i]) && std::isnan(sb.ranges_m[i])));
    }
    differs = differs || a.world().occupancy() != c.world().occupancy();
    a.advance();
    b.advance();
    c.advance();
  }
  EXPECT_TRUE(differs);  // another run seed, another day
}

// ---- drifting odometry -------------------------------------------------------------------

// The sample variance of the last pose's error of `runs` runs of `motion` (one true pose per
// step from the start (0, 0, 0)), for x, y and yaw.
std::array<double, 3> driftVariance(const core::OdometryNoise& noise, int runs, int steps,
                                    const std::function<core::Pose2D(int)>& truth_at) {
  std::array<double, 3> sum{};
  std::array<double, 3> sum_sq{};
  for (int run = 0; run < runs; ++run) {
    DriftingOdometry odometry(noise, mixSeed(static_cast<std::uint64_t>(run) + 100));
    core::Pose2D last;
    for (int step = 0; step <= steps; ++step) last = odometry.update(truth_at(step));
    const core::Pose2D truth = truth_at(steps);
    const std::array<double, 3> error{last.x_m - truth.x_m, last.y_m - truth.y_m,
                                      std::remainder(last.yaw_rad - truth.yaw_rad, 2.0 * kPi)};
    for (int k = 0; k < 3; ++k) {
      sum[k] += error[k];
      sum_sq[k] += error[k] * error[k];
    }
  }
  std::array<double, 3> variance{};
  for (int k = 0; k < 3; ++k) variance[k] = (sum_sq[k] - sum[k] * sum[k] / runs) / (runs - 1);
  return variance;
}

TEST(DriftingOdometry, WithoutNoiseItIsTheTruth) {
  const LoopPath path({{0.0, 0.0}, {6.0, 0.0}, {6.0, 4.0}, {0.0, 4.0}}, 0.35);
  DriftingOdometry odometry(core::OdometryNoise{}, 7);
  for (int step = 0; step < 200; ++step) {
    const core::Pose2D truth = path.poseAt(step);
    const core::Pose2D read = odometry.update(truth);
    ASSERT_NEAR(read.x_m, truth.x_m, 1e-9) << step;
    ASSERT_NEAR(read.y_m, truth.y_m, 1e-9) << step;
    ASSERT_NEAR(std::remainder(read.yaw_rad - truth.yaw_rad, 2.0 * kPi), 0.0, 1e-9) << step;
  }
}

TEST(DriftingOdometry, TranslationNoiseGrowsWithTheDistanceAsTheModelSays) {
  // 400 steps of 0.5 m straight ahead, alpha3 = 0.01: each step's length has variance
  // 0.01 * 0.25, so the end's x error has variance 400 * 0.0025 = 1 m^2; nothing turns.
  core::OdometryNoise noise;
  noise.trans_from_trans = 0.01;
  const std::array<double, 3> variance =
      driftVariance(noise, 400, 400, [](int step) { return core::Pose2D{0.5 * step, 0.0, 0.0}; });
  EXPECT_NEAR(variance[0], 1.0, 0.2);  // the sample variance of 400 runs: sd 0.07
  EXPECT_EQ(variance[1], 0.0);
  EXPECT_EQ(variance[2], 0.0);
}

TEST(DriftingOdometry, RotationNoiseGrowsWithTheTurnsAsTheModelSays) {
  // Turning on the spot 0.5 rad per step for 100 steps, alpha1 = 0.01: each turn has
  // variance 0.01 * 0.25, the end's heading 100 * 0.0025 = 0.25 rad^2; nothing moves.
  core::OdometryNoise noise;
  noise.rot_from_rot = 0.01;
  const std::array<double, 3> variance =
      driftVariance(noise, 400, 100, [](int step) { return core::Pose2D{1.0, 2.0, 0.5 * step}; });
  EXPECT_NEAR(variance[2], 0.25, 0.05);
  EXPECT_EQ(variance[0], 0.0);
  EXPECT_EQ(variance[1], 0.0);
}

TEST(DriftingOdometry, SameSeedSameDriftAndBadNoiseIsRefused) {
  core::OdometryNoise noise{0.02, 0.01, 0.02, 0.01};
  const LoopPath path({{0.0, 0.0}, {6.0, 0.0}, {6.0, 4.0}}, 0.4);
  DriftingOdometry a(noise, 3);
  DriftingOdometry b(noise, 3);
  DriftingOdometry c(noise, 4);
  core::Pose2D pa;
  core::Pose2D pc;
  for (int step = 0; step < 50; ++step) {
    pa = a.update(path.poseAt(step));
    const core::Pose2D pb = b.update(path.poseAt(step));
    ASSERT_EQ(pa.x_m, pb.x_m);
    ASSERT_EQ(pa.yaw_rad, pb.yaw_rad);
    pc = c.update(path.poseAt(step));
  }
  EXPECT_NE(pa.x_m, pc.x_m);
  EXPECT_GT(std::hypot(pa.x_m - path.poseAt(49).x_m, pa.y_m - path.poseAt(49).y_m), 0.0);
  for (const double bad : {-0.1, std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity()}) {
    core::OdometryNoise wrong;
    wrong.trans_from_rot = bad;
    EXPECT_THROW(DriftingOdometry(wrong, 1), std::invalid_argument);
  }
}

}  // namespace
}  // namespace evaluation
}  // namespace dynamic_occupancy_grid
