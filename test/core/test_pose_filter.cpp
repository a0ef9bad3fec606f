// Tests of mapping under pose uncertainty (core/pose/motion_model.h, core/pose/resampling.h,
// core/pose/particle_map.h, core/pose/pose_filter.h): the odometry motion model's formulas, the
// particle maps' closed-form cells against the core Mapper fed the same scans at the same
// poses, copy-on-write tiles, a scan's evidence and its likelihood against sums written out
// here, the filter on a room with drifting odometry, where it must end nearer the truth
// than odometry, and mapping at the filter's corrected poses (core/pose/corrected_mapping.h).

#include "dynamic_occupancy_grid/core/pose/pose_filter.h"
#include "dynamic_occupancy_grid/core/pose/corrected_mapping.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <functional>
#include <iostream>
#include <cmath>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <random>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/layers/model_io.h"
#include "dynamic_occupancy_grid/core/pose/resampling.h"

namespace dog = dynamic_occupancy_grid::core;

namespace {

constexpr double kPi = 3.14159265358979323846;

// --- a room to drive in: axis-aligned boxes, rays cast exactly -----------------------------
struct Box {
  double min_x, min_y, max_x, max_y;
};

// Distance along (cos a, sin a) from (x, y) to the nearest box side; +inf if none.
double castRay(const std::vector<Box>& boxes, double x, double y, double angle) {
  const double dx = std::cos(angle);
  const double dy = std::sin(angle);
  double nearest = std::numeric_limits<double>::infinity();
  for (const Box& box : boxes) {
    for (const double side_x : {box.min_x, box.max_x}) {
      if (std::abs(dx) < 1e-12) continue;
      const double t = (side_x - x) / dx;
      const double hit_y = y + t * dy;
      if (t > 1e-9 && hit_y >= box.min_y && hit_y <= box.max_y) nearest = std::min(nearest, t);
    }
    for (const double side_y : {box.min_y, box.max_y}) {
      if (std::abs(dy) < 1e-12) continue;
      const double t = (side_y - y) / dy;
      const double hit_x = x + t * dx;
      if (t > 1e-9 && hit_x >= box.min_x && hit_x <= box.max_x) nearest = std::min(nearest, t);
    }
  }
  return nearest;
}

// A 12 m x 8 m room (walls 0.2 m thick) with three pillars and a shelf.
std::vector<Box> room() {
  return {{-0.2, -0.2, 12.2, 0.0}, {-0.2, 8.0, 12.2, 8.2}, {-0.2, 0.0, 0.0, 8.0}, {12.0, 0.0, 12.2, 8.0},
          {3.0, 3.0, 3.4, 3.4},    {8.0, 4.6, 8.4, 5.0},   {5.5, 6.5, 7.5, 7.0}, {10.0, 1.0, 10.6, 2.2}};
}

dog::Scan simulatedScan(const std::vector<Box>& boxes, const dog::Pose2D& pose, double stamp_s, std::mt19937_64& rng,
                        double noise_m, std::size_t beams = 181) {
  dog::Scan scan;
  scan.stamp_s = stamp_s;
  scan.laser_pose = pose;
  scan.angle_min_rad = -kPi / 2;
  scan.angle_increment_rad = kPi / static_cast<double>(beams - 1);
  scan.range_min_m = 0.05;
  scan.range_max_m = 20.0;
  std::normal_distribution<double> noise(0.0, noise_m);
  for (std::size_t i = 0; i < beams; ++i) {
    const double range = castRay(boxes, pose.x_m, pose.y_m, pose.yaw_rad + scan.angle_min_rad + i * scan.angle_increment_rad);
    scan.ranges_m.push_back(static_cast<float>(noise_m > 0.0 ? range + noise(rng) : range));
  }
  return scan;
}

void expectPose(const dog::Pose2D& actual, const dog::Pose2D& expected, double tolerance) {
  EXPECT_NEAR(actual.x_m, expected.x_m, tolerance);
  EXPECT_NEAR(actual.y_m, expected.y_m, tolerance);
  EXPECT_NEAR(std::remainder(actual.yaw_rad - expected.yaw_rad, 2 * kPi), 0.0, tolerance);
}

// --- the motion model ----------------------------------------------------------------------

TEST(MotionModel, MotionBetweenTwoPosesTakesOneToTheOther) {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> coordinate(-5.0, 5.0);
  std::uniform_real_distribution<double> angle(-kPi, kPi);
  for (int i = 0; i < 200; ++i) {
    const dog::Pose2D from{coordinate(rng), coordinate(rng), angle(rng)};
    const dog::Pose2D to{coordinate(rng), coordinate(rng), angle(rng)};
    expectPose(dog::applyMotion(from, dog::odometryMotion(from, to)), to, 1e-9);
    // frame * (frame^-1 * pose) = pose
    expectPose(dog::composePose(from, dog::relativePose(from, to)), to, 1e-9);
  }
  // A turn on the spot is all second rotation.
  const dog::OdometryMotion turn = dog::odometryMotion({1.0, 2.0, 0.5}, {1.0, 2.0, 1.5});
  EXPECT_EQ(turn.rot1_rad, 0.0);
  EXPECT_EQ(turn.trans_m, 0.0);
  EXPECT_NEAR(turn.rot2_rad, 1.0, 1e-12);
}

TEST(MotionModel, NoiseHasTheModelsVariances) {
  const dog::OdometryMotion motion{0.3, 2.0, -0.2};
  const dog::OdometryNoise noise{0.1, 0.02, 0.05, 0.3};
  const dog::OdometryMotion same = dog::perturbMotion(motion, noise, {0.0, 0.0, 0.0});
  EXPECT_EQ(same.rot1_rad, motion.rot1_rad);
  EXPECT_EQ(same.trans_m, motion.trans_m);
  EXPECT_EQ(same.rot2_rad, motion.rot2_rad);
  // One standard deviation each: the square roots of Probabilistic Robotics' §5.4 variances.
  const dog::OdometryMotion read = dog::perturbMotion(motion, noise, {1.0, -1.0, 2.0});
  EXPECT_NEAR(read.rot1_rad, 0.3 + std::sqrt(0.1 * 0.09 + 0.02 * 4.0), 1e-12);
  EXPECT_NEAR(read.trans_m, 2.0 - std::sqrt(0.05 * 4.0 + 0.3 * (0.09 + 0.04)), 1e-12);
  EXPECT_NEAR(read.rot2_rad, -0.2 + 2.0 * std::sqrt(0.1 * 0.04 + 0.02 * 4.0), 1e-12);
  EXPECT_THROW((dog::OdometryNoise{-0.1, 0, 0, 0}.validate()), std::invalid_argument);
  EXPECT_THROW((dog::OdometryNoise{0, 0, std::nan(""), 0}.validate()), std::invalid_argument);
}

TEST(MotionModel, MovingBackwardsHasTheNoiseOfMovingForwards) {
  // A laser facing back (or a robot in reverse) travels at pi to its heading: the rotations
  // read from odometry are about pi, but nothing turned. The noise is that of the forward move.
  const dog::OdometryNoise noise{0.3, 0.02, 0.05, 0.1};
  const dog::OdometryMotion forward = dog::odometryMotion({0.0, 0.0, 0.0}, {0.5, 0.05, 0.1});
  const dog::OdometryMotion backward = dog::odometryMotion({0.0, 0.0, 0.0}, {-0.5, -0.05, 0.1});
  EXPECT_NEAR(std::abs(backward.rot1_rad), kPi - std::abs(forward.rot1_rad), 1e-12);
  const std::array<double, 3> normals{1.0, -0.7, 0.4};
  const dog::OdometryMotion f = dog::perturbMotion(forward, noise, normals);
  const dog::OdometryMotion b = dog::perturbMotion(backward, noise, normals);
  EXPECT_NEAR(b.rot1_rad - backward.rot1_rad, f.rot1_rad - forward.rot1_rad, 1e-12);
  EXPECT_NEAR(b.trans_m - backward.trans_m, f.trans_m - forward.trans_m, 1e-12);
  EXPECT_NEAR(b.rot2_rad - backward.rot2_rad, f.rot2_rad - forward.rot2_rad, 1e-12);
  EXPECT_LT(std::abs(b.rot1_rad - backward.rot1_rad), 0.1);  // a half turn's noise would be 1.7 rad
}

TEST(Resampling, EffectiveSampleSize) {
  EXPECT_DOUBLE_EQ(dog::effectiveSampleSize({1.0, 1.0, 1.0, 1.0}), 4.0);
  EXPECT_DOUBLE_EQ(dog::effectiveSampleSize({0.0, 5.0, 0.0}), 1.0);
  EXPECT_DOUBLE_EQ(dog::effectiveSampleSize({3.0, 1.0}), 16.0 / 10.0);
  EXPECT_EQ(dog::effectiveSampleSize({0.0, 0.0}), 0.0);
  int calls = 0;
  const auto copies = dog::residualResample({0.5, 0.25, 0.25}, 4, [&calls] { return ++calls, 0.5; });
  EXPECT_EQ(copies, (std::vector<std::size_t>{2, 1, 1}));
  EXPECT_EQ(calls, 0);  // the floors alone make the four
}

// --- the particle maps ---------------------------------------------------------------------

TEST(ParticleMap, CellsFollowTheFilterStepByStep) {
  // Closed-form prediction across gaps against one predictOneStep per step, then Bayes.
  const dog::UniformTransitions transitions({0.07, 0.03});
  dog::ParticleMap map;
  double reference = 0.5;
  std::int64_t last = 0;
  map.update(-40, 17, 0, 1.2, transitions, 0.5);
  reference = dog::bayesUpdate(dog::predictOneStep(reference, {0.07, 0.03}), 1.2);  // the prior, one step before
  for (const auto& [step, llr] : std::vector<std::pair<std::int64_t, double>>{{1, -0.4}, {5, 2.0}, {5, -0.3}, {30, -1.1}}) {
    for (std::int64_t k = last; k < step; ++k) reference = dog::predictOneStep(reference, {0.07, 0.03});
    EXPECT_NEAR(map.predicted(-40, 17, step, transitions, 0.5), reference, 2e-6) << step;
    map.update(-40, 17, step, llr, transitions, 0.5);
    reference = static_cast<float>(dog::bayesUpdate(reference, llr));
    last = step;
    EXPECT_EQ(map.lastStep(-40, 17), step);
  }
  EXPECT_NEAR(map.predicted(-41, 17, 3, transitions, 0.3), 0.3 * 0.97 + 0.7 * 0.07, 1e-15);  // never updated
  EXPECT_EQ(map.lastStep(5, 5), dog::kNeverObserved);
}

TEST(ParticleMap, ReaderAndWriterOnEveryTileIncludingMinusOne) {
  // The Reader and Writer remember their last tile by its key; the tile of cells (-32..-1,
  // -32..-1) has the key of all ones, which once stood for "no tile yet" (a real robot's map
  // around a negative origin crashed the filter).
  const dog::UniformTransitions transitions({0.02, 0.01});
  const std::vector<std::pair<std::int32_t, std::int32_t>> cells = {{-1, -1}, {-5, -3}, {-32, -32}, {-33, -1},
                                                                     {0, 0}, {-1, 0}, {31, -1}, {40, 70}};
  dog::ParticleMap written;
  dog::ParticleMap reference;
  {
    dog::ParticleMap::Writer writer(written);
    for (std::size_t i = 0; i < cells.size(); ++i) {
      const double llr = 0.3 * static_cast<double>(i) - 1.0;
      writer.update(cells[i].first, cells[i].second, 2, llr, transitions, 0.5);
      reference.update(cells[i].first, cells[i].second, 2, llr, transitions, 0.5);
    }
  }
  dog::ParticleMap::Reader reader(written);
  for (const auto& [x, y] : cells) {
    EXPECT_EQ(reader.lastStep(x, y), 2) << x << ", " << y;
    EXPECT_EQ(reader.predicted(x, y, 4, transitions, 0.5), reference.predicted(x, y, 4, transitions, 0.5))
        << x << ", " << y;
  }
  dog::ParticleMap::Reader first_read(written);  // a reader whose first cell is in that tile
  EXPECT_EQ(first_read.lastStep(-1, -1), 2);
}

TEST(ParticleMap, CopiesShareTilesUntilOneWrites) {
  const dog::UniformTransitions transitions({0.0, 0.0});
  dog::ParticleMap a;
  for (std::int32_t x = 0; x < 100; x += 10) a.update(x, 3, 0, 1.0, transitions, 0.5);
  ASSERT_EQ(a.tileCount(), 3u);  // x 0..90: tiles 0, 1, 2 (32 cells each)
  const std::size_t one_map = dog::ParticleMap::distinctTileBytes({&a});
  dog::ParticleMap b = a;
  EXPECT_EQ(a.sharedTileCount(), 3u);
  EXPECT_EQ(dog::ParticleMap::distinctTileBytes({&a, &b}), one_map);
  b.update(10, 3, 1, -2.0, transitions, 0.5);  // tile of x 0..31
  EXPECT_FALSE(a.sharesTileWith(b, 10, 3));
  EXPECT_TRUE(a.sharesTileWith(b, 40, 3));
  EXPECT_EQ(dog::ParticleMap::distinctTileBytes({&a, &b}), one_map + sizeof(dog::ParticleMap::Tile));
  // The copy's write left the original alone.
  EXPECT_NEAR(a.predicted(10, 3, 1, transitions, 0.5), dog::bayesUpdate(0.5, 1.0), 1e-6);  // static: no drift
  EXPECT_NEAR(b.predicted(10, 3, 1, transitions, 0.5), dog::bayesUpdate(dog::bayesUpdate(0.5, 1.0), -2.0), 1e-6);
  // Negative coordinates have tiles of their own.
  b.update(-1, -1, 1, 1.0, transitions, 0.5);
  EXPECT_EQ(b.tileCount(), 4u);
  EXPECT_TRUE(b.bounds().contains(-32, -32));
  EXPECT_FALSE(b.bounds().contains(-33, 0));
}

// The particle map of one particle that never moves off the true poses is the core Mapper's
// map of the same scans (one scan per step, learning off): same cells, same evidence, same
// closed-form prediction across the steps a cell was not seen.
TEST(ParticleMap, EqualsTheMappersMapOnTheSameScansAndPoses) {
  const std::vector<Box> boxes = room();
  dog::MapperConfig mapper_config;
  mapper_config.resolution_m = 0.1;
  mapper_config.time_step_s = 1.0;
  mapper_config.learn_transitions = false;
  mapper_config.prior_transitions = {0.04, 0.02};
  mapper_config.max_free_range_m = 5.0;
  dog::Mapper mapper(mapper_config);
  dog::PoseFilterConfig config;
  config.particles = 1;
  config.resolution_m = 0.1;
  config.max_free_range_m = 5.0;
  config.motion_noise = {};
  config.scan_matching = false;
  config.update_distance_m = 1e-6;
  config.update_angle_rad = 1e-6;
  dog::PoseFilter filter(config, std::make_shared<dog::UniformTransitions>(dog::TransitionParams{0.04, 0.02}));
  std::mt19937_64 rng(1);
  std::vector<dog::Pose2D> poses;
  for (int i = 0; i < 12; ++i) poses.push_back({1.5 + 0.6 * i, 2.0 + 0.25 * std::sin(i), 0.3 * i});
  for (std::size_t i = 0; i < poses.size(); ++i) {
    const dog::Scan scan = simulatedScan(boxes, poses[i], static_cast<double>(i), rng, 0.01);
    ASSERT_EQ(mapper.integrate(scan).status, dog::ScanStatus::kIntegrated);
    ASSERT_TRUE(filter.integrate(scan).updated) << i;
  }
  mapper.finishStep();
  const std::int64_t last = static_cast<std::int64_t>(poses.size()) - 1;
  const dog::ParticleMap& map = filter.particles()[0].map;
  const dog::CellBox box = map.bounds();
  int compared = 0;
  for (std::int32_t y = box.min_y; y <= box.max_y; ++y) {
    for (std::int32_t x = box.min_x; x <= box.max_x; ++x) {
      if (map.lastStep(x, y) == dog::kNeverObserved) continue;
      ASSERT_NEAR(map.predicted(x, y, last + 3, filter.transitions(), 0.5), mapper.beliefAt(x, y, last + 3), 2e-6)
          << x << ", " << y;
      ++compared;
    }
  }
  EXPECT_GT(compared, 3000);
  // And a cell the Mapper saw is one the particle saw.
  EXPECT_NE(map.lastStep(static_cast<std::int32_t>(std::floor(1.5 / 0.1)) + 5, 20), dog::kNeverObserved);
}

// --- evidence and weights ------------------------------------------------------------------

TEST(PoseFilter, ScanEvidenceCountsEachBeamsCells) {
  // Four beams from the centre of cell (0, 0), 0.1 m cells (the others ignored, NaN): along
  // +x to 0.5 m (a hit in cell 5, misses in 0..4), along +y without return (free to 0.3 m:
  // misses in 0..3), along -x to 0.3 m (a hit in cell -3, misses in -2..0), and along +x
  // again to 0.22 m, a hit in cell 2 that wins over the first beam's miss there. A scan
  // observes each cell once.
  const float nan = std::numeric_limits<float>::quiet_NaN();
  dog::Scan scan;
  scan.angle_min_rad = 0.0;
  scan.angle_increment_rad = kPi / 4;
  scan.range_min_m = 0.01;
  scan.range_max_m = 2.0;
  scan.ranges_m = {0.5f, nan, std::numeric_limits<float>::infinity(), nan, 0.3f, nan, nan, nan, 0.22f};
  const auto evidence = dog::scanEvidence(scan, {0.05, 0.05, 0.0}, 0.1, 0.3, 10.0);
  std::map<std::pair<int, int>, std::pair<unsigned, unsigned>> cells;
  for (const dog::CellEvidence& e : evidence) cells[{e.x, e.y}] = {e.hits, e.misses};
  const std::pair<unsigned, unsigned> hit{1, 0};
  const std::pair<unsigned, unsigned> miss{0, 1};
  const std::map<std::pair<int, int>, std::pair<unsigned, unsigned>> expected = {
      {{0, 0}, miss}, {{1, 0}, miss},  {{2, 0}, hit},   {{3, 0}, miss},  {{4, 0}, miss},  {{5, 0}, hit},
      {{0, 1}, miss}, {{0, 2}, miss},  {{0, 3}, miss},  {{-1, 0}, miss}, {{-2, 0}, miss}, {{-3, 0}, hit}};
  EXPECT_EQ(cells, expected);
  EXPECT_EQ(evidence.size(), expected.size());  // each cell once
}

// The nearest occupied cell by brute force: every cell of the map's tiles.
double bruteNearestOccupied(const dog::ParticleMap& map, const dog::TransitionSource& transitions, double x_m,
                            double y_m, double resolution_m, double max_distance_m, std::int64_t step) {
  double best = max_distance_m;
  const dog::CellBox box = map.bounds();
  for (std::int32_t y = box.min_y; y <= box.max_y; ++y) {
    for (std::int32_t x = box.min_x; x <= box.max_x; ++x) {
      if (map.lastStep(x, y) == dog::kNeverObserved) continue;
      if (map.predicted(x, y, step, transitions, 0.5) <= 0.5) continue;
      best = std::min(best, std::hypot(x_m - (x + 0.5) * resolution_m, y_m - (y + 0.5) * resolution_m));
    }
  }
  return best;
}

TEST(PoseFilter, LikelihoodFieldDistanceIsTheNearestOccupiedCell) {
  // Random cells hit (occupied) or missed (free) on tiles around -1 and 0; every query
  // point's distance against the brute force over all cells, with and without the cap.
  dog::ParticleMap map;
  const dog::UniformTransitions transitions(dog::TransitionParams{0.05, 0.1});
  std::mt19937_64 rng(11);
  std::uniform_int_distribution<std::int32_t> cell(-40, 40);
  for (int i = 0; i < 300; ++i) map.update(cell(rng), cell(rng), 2, std::log(0.7 / 0.2), transitions, 0.5);
  for (int i = 0; i < 300; ++i) map.update(cell(rng), cell(rng), 2, std::log(0.3 / 0.8), transitions, 0.5);
  const dog::CellBox box = map.bounds();
  ASSERT_LE(box.min_x, -33);  // the box's cells all searched by the reference
  std::uniform_real_distribution<double> coordinate(-2.2, 2.2);
  int capped = 0;
  for (const double max_distance : {0.05, 0.3, 1.0, 3.2}) {
    for (int i = 0; i < 400; ++i) {
      const double x = coordinate(rng);
      const double y = coordinate(rng);
      const double expected = bruteNearestOccupied(map, transitions, x, y, 0.05, max_distance, 5);
      EXPECT_NEAR(dog::nearestOccupiedDistance(map, transitions, x, y, 0.05, max_distance, 5, 0.5), expected, 1e-12)
          << x << ", " << y << " max " << max_distance;
      if (expected == max_distance) ++capped;
    }
  }
  EXPECT_GT(capped, 100);
  EXPECT_LT(capped, 1400);
  // An empty map: the cap.
  EXPECT_EQ(dog::nearestOccupiedDistance(dog::ParticleMap{}, transitions, 0.3, 0.2, 0.05, 0.5, 1, 0.5), 0.5);
}

TEST(PoseFilter, GuardBoundsTheNetCorrectionByTheMotionModel) {
  // The anchor at the origin with odometry at (1, 0, 0); 10 m of straight travel since, with
  // heading variance 0.01 rad^2 (sigma 0.1) and translation variance 0.0004 m^2 accumulated.
  dog::TrajectoryNode anchor;
  anchor.pose = {0.0, 0.0, 0.0};
  anchor.odometry = {1.0, 0.0, 0.0};
  anchor.travelled_m = 2.0;
  anchor.heading_variance = 0.001;
  anchor.translation_variance = 0.0001;
  const dog::Pose2D odometry{11.0, 0.0, 0.0};  // odometry's prediction from the anchor: (10, 0, 0)
  const double sigma_h = 0.1;
  const double sigma_p = std::sqrt(0.0004 + 100.0 * 0.01 / 3.0 + 0.05 * 0.05);
  const auto accepts = [&](const dog::Pose2D& pose) {
    return dog::guardAccepts(anchor, pose, odometry, 12.0, 0.011, 0.0005, 3.0, 0.05);
  };
  EXPECT_TRUE(accepts({10.0, 0.0, 0.0}));
  EXPECT_TRUE(accepts({10.0, 0.0, 2.9 * sigma_h}));
  EXPECT_TRUE(accepts({10.0, 0.0, -2.9 * sigma_h}));
  EXPECT_FALSE(accepts({10.0, 0.0, 3.1 * sigma_h}));
  EXPECT_FALSE(accepts({10.0, 0.0, -3.1 * sigma_h}));
  EXPECT_TRUE(accepts({10.0, 2.9 * sigma_p, 0.0}));
  EXPECT_FALSE(accepts({10.0, 3.1 * sigma_p, 0.0}));
  EXPECT_FALSE(accepts({10.0 - 2.2 * sigma_p, 2.2 * sigma_p, 0.0}));  // 3.1 sigma in all
  // The prediction turns with the anchor: odometry's motion since the anchor read from the
  // anchor's corrected pose (here turned by pi/2, so odometry's +x is the map's +y).
  anchor.pose = {0.0, 0.0, kPi / 2};
  EXPECT_TRUE(accepts({0.0, 10.0, kPi / 2}));
  EXPECT_FALSE(accepts({10.0, 0.0, kPi / 2}));
  // Over one short step the same correction is refused: the bound grows with the travel.
  anchor.pose = {0.0, 0.0, 0.0};
  anchor.travelled_m = 11.5;
  anchor.heading_variance = 0.0105;
  anchor.translation_variance = 0.00049;
  anchor.odometry = {10.5, 0.0, 0.0};
  anchor.pose = {9.5, 0.0, 0.0};
  EXPECT_TRUE(accepts({10.0, 0.0, 0.02}));
  EXPECT_FALSE(accepts({10.0, 0.0, 0.1}));
  // Odometry itself always passes.
  EXPECT_TRUE(dog::guardAccepts(anchor, {10.0, 0.0, 0.0}, odometry, 12.0, 0.0105, 0.00049, 3.0, 0.0));
}

TEST(PoseFilter, WeightIsTheLikelihoodFieldOfTheSubsampledBeams) {
  const std::vector<Box> boxes = room();
  auto transitions = std::make_shared<dog::UniformTransitions>(dog::TransitionParams{0.05, 0.1});
  dog::PoseFilterConfig config;
  config.particles = 1;
  config.resolution_m = 0.1;
  config.motion_noise = {};
  config.scan_matching = false;
  config.resample_below = 0.0;
  config.weight_beams = 60;
  dog::PoseFilter filter(config, transitions);
  std::mt19937_64 rng(2);
  ASSERT_TRUE(filter.integrate(simulatedScan(boxes, {2.0, 2.0, 0.0}, 0.0, rng, 0.01)).updated);
  const dog::ParticleMap before = filter.particles()[0].map;
  const dog::Pose2D next{2.6, 2.1, 0.2};
  const dog::Scan scan = simulatedScan(boxes, next, 3.5, rng, 0.01);
  ASSERT_TRUE(filter.integrate(scan).updated);
  // The beams with a return, 60 of them evenly spread; each end scored against the map of
  // the first scan predicted to step 3 (brute force), or explained if the map has not been
  // near it.
  std::vector<std::array<double, 2>> ends;
  for (std::size_t i = 0; i < scan.ranges_m.size(); ++i) {
    const double range = scan.ranges_m[i];
    if (!(range >= scan.range_min_m && range < scan.range_max_m)) continue;
    const double angle = next.yaw_rad + scan.angle_min_rad + static_cast<double>(i) * scan.angle_increment_rad;
    ends.push_back({next.x_m + range * std::cos(angle), next.y_m + range * std::sin(angle)});
  }
  ASSERT_GT(ends.size(), 60u);
  long double expected = 0.0L;
  int unmapped = 0;
  for (std::size_t k = 0; k < 60; ++k) {
    const auto& end = ends[(2 * k + 1) * ends.size() / 120];
    const auto cx = static_cast<std::int32_t>(std::floor(end[0] / 0.1));
    const auto cy = static_cast<std::int32_t>(std::floor(end[1] / 0.1));
    bool mapped = false;
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dx = -1; dx <= 1; ++dx) mapped = mapped || before.lastStep(cx + dx, cy + dy) != dog::kNeverObserved;
    }
    double d = 0.0;
    if (mapped) {
      d = bruteNearestOccupied(before, *transitions, end[0], end[1], 0.1, config.weight_max_distance_m, 3);
    } else {
      ++unmapped;
    }
    expected += std::log(0.95L * std::exp(-d * d / (2.0L * 0.15L * 0.15L)) + 0.05L);
  }
  EXPECT_GT(unmapped, 0);
  EXPECT_LT(unmapped, 60);
  EXPECT_NEAR(filter.particles()[0].log_weight, static_cast<double>(expected), 1e-9);
  EXPECT_LT(static_cast<double>(expected), -1.0);  // some beams off the first scan's walls
  expectPose(filter.particles()[0].pose, next, 1e-9);
  // Not moved enough: the scan is not used.
  EXPECT_FALSE(filter.integrate(simulatedScan(boxes, {2.65, 2.1, 0.25}, 4.0, rng, 0.01)).updated);
  EXPECT_EQ(filter.updates(), 2u);
  // Time going back before the last update's step is refused.
  EXPECT_THROW(filter.integrate(simulatedScan(boxes, {4.0, 2.0, 0.0}, 1.0, rng, 0.01)), std::invalid_argument);
}

TEST(PoseFilter, TheCorrectionTestComparesTwoPosesOnTheSameBeams) {
  // One wall (its face at x = 4 m) mapped from (2, 0, 0); the same scan again. A pose 0.3 m
  // nearer the wall puts every end behind its face, in cells no beam has reached: there
  // each end counts as explained, so alone that pose scores better than the true one. On the
  // same beams (compared_with) none is left to tell them apart, and nothing is gained.
  const std::vector<Box> wall = {{4.0, -30.0, 4.2, 30.0}};
  auto transitions = std::make_shared<dog::UniformTransitions>(dog::TransitionParams{0.0, 0.0});
  dog::PoseFilterConfig config;
  config.particles = 1;
  config.resolution_m = 0.05;
  config.motion_noise = {};
  config.scan_matching = false;
  dog::PoseFilter filter(config, transitions);
  std::mt19937_64 rng(4);
  const dog::Pose2D truth{2.0, 0.0, 0.0};
  const dog::Scan scan = simulatedScan(wall, truth, 0.0, rng, 0.0);
  ASSERT_TRUE(filter.integrate(scan).updated);
  const dog::ParticleMap& map = filter.particles()[0].map;
  const std::vector<std::array<double, 2>> beams = dog::weightBeams(scan, config.weight_beams);
  ASSERT_EQ(beams.size(), 60u);
  const auto field = [&](const dog::Pose2D& pose, const dog::Pose2D* compared_with) {
    return dog::fieldLogLikelihood(map, *transitions, config, beams, pose, 0, compared_with);
  };
  const dog::Pose2D behind{2.3, 0.0, 0.0};
  EXPECT_LT(field(truth, nullptr), -0.05);  // the ends 0-2.5 cm from the hit cells' centres
  EXPECT_EQ(field(behind, nullptr), 0.0);   // every end explained
  EXPECT_EQ(field(behind, &truth), 0.0);
  EXPECT_EQ(field(truth, &behind), 0.0);
  // A pose whose ends fall in front of the wall, on cells its beams crossed, still loses
  // to the truth on the beams both have.
  const dog::Pose2D short_of{1.85, 0.0, 0.0};
  EXPECT_LT(field(short_of, &truth), field(truth, &short_of) - 5.0);
}

TEST(PoseFilter, ARefusedPoseTakesOdometrysIncrementAndItsWeight) {
  // Noisy samples that the guard (a bound of almost 0 sigma) or the correction test (a gain
  // no scan reaches) refuses: the particle moves by odometry's increment and is weighed
  // there, exactly as a filter without noise.
  const std::vector<Box> boxes = room();
  auto transitions = std::make_shared<dog::UniformTransitions>(dog::TransitionParams{0.0, 0.0});
  dog::PoseFilterConfig exact;
  exact.particles = 3;
  exact.resolution_m = 0.1;
  exact.motion_noise = {};
  exact.scan_matching = false;
  exact.resample_below = 0.0;
  exact.guard_sigmas = 0.0;
  exact.correction_test = false;
  dog::PoseFilterConfig guarded = exact;
  guarded.motion_noise = {0.05, 0.05, 0.05, 0.05};
  guarded.guard_sigmas = 1e-6;
  guarded.correction_test = true;
  dog::PoseFilterConfig tested = guarded;
  tested.guard_sigmas = 0.0;
  tested.correction_min_gain = 1e6;
  std::vector<std::unique_ptr<dog::PoseFilter>> filters;
  for (const auto& config : {exact, guarded, tested}) filters.push_back(std::make_unique<dog::PoseFilter>(config, transitions));
  const std::vector<dog::Pose2D> poses = {{2.0, 2.0, 0.0}, {2.6, 2.1, 0.2}, {3.2, 2.3, 0.3}};
  for (std::size_t i = 0; i < poses.size(); ++i) {
    for (auto& filter : filters) {
      std::mt19937_64 rng(3 + i);
      ASSERT_TRUE(filter->integrate(simulatedScan(boxes, poses[i], 2.0 * i, rng, 0.01)).updated);
    }
  }
  EXPECT_EQ(filters[0]->guardRefusals(), 0u);
  for (std::size_t f = 1; f < filters.size(); ++f) {
    EXPECT_EQ(filters[f]->guardRefusals(), 6u) << f;  // 3 particles, 2 updates
    for (std::size_t p = 0; p < 3; ++p) {
      expectPose(filters[f]->particles()[p].pose, filters[0]->particles()[p].pose, 1e-9);
      EXPECT_NEAR(filters[f]->particles()[p].log_weight, filters[0]->particles()[p].log_weight, 1e-9) << f;
    }
  }
  EXPECT_LT(filters[0]->particles()[0].log_weight, -0.5);  // a weight, not the maximum 0
}

// A corridor (faces on cell centres), 30 particles of motion noise `alpha` (all four), two
// scans 0.5 m apart whose second odometry is turned `turn_rad` too far: the filter after them.
// The scan shows the heading (the walls) but not the position along the corridor.
std::unique_ptr<dog::PoseFilter> corridorAfterATurn(double alpha, double turn_rad) {
  const std::vector<Box> corridor = {{-30.0, -1.725, 30.0, -1.525}, {-30.0, 1.525, 30.0, 1.725}};
  auto transitions = std::make_shared<dog::UniformTransitions>(dog::TransitionParams{0.0, 0.0});
  dog::PoseFilterConfig config;
  config.particles = 30;
  config.resolution_m = 0.05;
  config.motion_noise = {alpha, alpha, alpha, alpha};
  config.resample_below = 0.0;
  const auto scanAt = [&](const dog::Pose2D& truth, const dog::Pose2D& odometry, double stamp_s) {
    std::mt19937_64 rng(5);
    dog::Scan scan = simulatedScan(corridor, truth, stamp_s, rng, 0.0, 361);
    scan.range_max_m = 4.0;  // the walls in view end 3.7 m along the corridor
    scan.laser_pose = odometry;
    return scan;
  };
  auto filter = std::make_unique<dog::PoseFilter>(config, transitions);
  EXPECT_TRUE(filter->integrate(scanAt({0.0, 0.0, 0.0}, {0.0, 0.0, 0.0}, 0.0)).updated);
  EXPECT_TRUE(filter->integrate(scanAt({0.5, 0.0, 0.0}, {0.5, 0.0, turn_rad}, 1.0)).updated);
  return filter;
}

TEST(PoseFilter, ARefusedSampleLeavesOdometrysIncrementMatched) {
  // The corridor, the second scan's odometry turned by 0.04 rad too much. A sample of the
  // motion model keeps its shift along the corridor after matching, and the correction test's
  // prior charges for that shift, so a sample with a large one is refused though its heading
  // is right (8 of these 30 without the second candidate). Odometry's increment matched is
  // then the particle's pose: every particle's heading comes out corrected.
  const auto filter = corridorAfterATurn(0.002, 0.04);
  for (const dog::Particle& particle : filter->particles()) {
    EXPECT_NEAR(particle.pose.yaw_rad, 0.0, 0.01);
    EXPECT_NEAR(particle.pose.y_m, 0.0, 0.02);
  }
  EXPECT_EQ(filter->guardRefusals(), 0u);
}

TEST(PoseFilter, TheCorrectionTestTakesAHeadingTheMatcherFound) {
  // The corridor with the default noise's size (alphas 0.001, as process_bag's and the
  // node's) and odometry turned by 0.05 rad too much, about 2 sigma of one update's heading:
  // the fast drift of a 5 % odometry. Matching finds the heading; the scan's gain over
  // odometry's increment, scored with the weight's flat 0.15 m field, did not make up for
  // the prior's cost, and the particles kept odometry's error. Scored with the matcher's
  // kernel (0.05 m) it does: every particle's heading comes out corrected.
  const auto filter = corridorAfterATurn(0.001, 0.05);
  for (const dog::Particle& particle : filter->particles()) {
    EXPECT_NEAR(particle.pose.yaw_rad, 0.0, 0.01);
    EXPECT_NEAR(particle.pose.y_m, 0.0, 0.02);
  }
}

TEST(PoseFilter, WeightsOfNearbyPosesDifferByAFewNats) {
  // The point of the likelihood field: two particles 5 cm apart differ by a few nats, not
  // the tens of a product over every cell. One particle each, a room mapped from the true
  // pose, the second scan's odometry off by 5 cm for the second filter.
  const std::vector<Box> boxes = room();
  auto transitions = std::make_shared<dog::UniformTransitions>(dog::TransitionParams{0.0, 0.0});
  dog::PoseFilterConfig config;
  config.particles = 1;
  config.resolution_m = 0.05;
  config.motion_noise = {};
  config.scan_matching = false;
  config.guard_sigmas = 0.0;
  config.correction_min_gain = 0.0;
  std::array<double, 2> weights{};
  for (int k = 0; k < 2; ++k) {
    dog::PoseFilter filter(config, transitions);
    std::mt19937_64 rng(4);
    for (int i = 0; i < 3; ++i) filter.integrate(simulatedScan(boxes, {2.0, 2.0, 0.0}, i, rng, 0.01));
    dog::Scan scan = simulatedScan(boxes, {2.6, 2.0, 0.0}, 3.0, rng, 0.01, 361);
    scan.laser_pose.y_m += 0.05 * k;
    ASSERT_TRUE(filter.integrate(scan).updated);
    weights[k] = filter.particles()[0].log_weight;
  }
  EXPECT_GT(weights[0] - weights[1], 0.5);
  EXPECT_LT(weights[0] - weights[1], 5.0);
}

// --- the filter on a drive with drifting odometry ------------------------------------------

struct DriveResult {
  double odometry_error_m = 0.0;  ///< mean position error over the drive
  double filter_error_m = 0.0;
  double filter_final_m = 0.0;
  double odometry_final_m = 0.0;
  std::size_t resamplings = 0;
  std::size_t peak_map_bytes = 0;
};

// `laps` laps around the room's pillars (a 5 m x 4 m rectangle), a pose every 0.2 m.
std::vector<dog::Pose2D> loopLaps(int laps) {
  const std::vector<std::array<double, 2>> corners = {{1.5, 1.5}, {6.5, 1.5}, {6.5, 5.5}, {1.5, 5.5}};
  std::vector<dog::Pose2D> poses;
  for (int lap = 0; lap < laps; ++lap) {
    for (std::size_t c = 0; c < corners.size(); ++c) {
      const auto& a = corners[c];
      const auto& b = corners[(c + 1) % corners.size()];
      const double heading = std::atan2(b[1] - a[1], b[0] - a[0]);
      const double length = std::hypot(b[0] - a[0], b[1] - a[1]);
      for (double s = 0.0; s < length; s += 0.2) poses.push_back({a[0] + s * std::cos(heading), a[1] + s * std::sin(heading), heading});
    }
  }
  return poses;
}

// Two laps around the room's pillars with odometry that drifts (the motion model's noise,
// rotation-heavy), the laser at the true pose, 5 scans per metre.
DriveResult drive(std::uint64_t seed, dog::PoseFilterConfig config) {
  const std::vector<Box> boxes = room();
  const std::vector<dog::Pose2D> truth = loopLaps(2);
  const dog::OdometryNoise drift{0.02, 0.002, 0.01, 0.01};
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal;
  dog::PoseFilter filter(config, std::make_shared<dog::UniformTransitions>(dog::TransitionParams{0.0, 0.0}));
  DriveResult result;
  dog::Pose2D odometry = truth[0];
  std::size_t updates = 0;
  for (std::size_t i = 0; i < truth.size(); ++i) {
    if (i > 0) {
      odometry = dog::applyMotion(odometry, dog::perturbMotion(dog::odometryMotion(truth[i - 1], truth[i]), drift,
                                                               {normal(rng), normal(rng), normal(rng)}));
    }
    dog::Scan scan = simulatedScan(boxes, truth[i], 0.5 * i, rng, 0.01);
    scan.laser_pose = odometry;
    const dog::PoseUpdate update = filter.integrate(scan);
    if (!update.updated) continue;
    result.peak_map_bytes = std::max(result.peak_map_bytes, update.map_bytes);
    ++updates;
    const dog::Pose2D corrected = dog::composePose(filter.mapToOdometry(), odometry);
    result.filter_final_m = std::hypot(corrected.x_m - truth[i].x_m, corrected.y_m - truth[i].y_m);
    result.odometry_final_m = std::hypot(odometry.x_m - truth[i].x_m, odometry.y_m - truth[i].y_m);
    result.filter_error_m += result.filter_final_m;
    result.odometry_error_m += result.odometry_final_m;
  }
  result.filter_error_m /= static_cast<double>(updates);
  result.odometry_error_m /= static_cast<double>(updates);
  result.resamplings = filter.resamplings();
  return result;
}

dog::PoseFilterConfig driveConfig() {
  dog::PoseFilterConfig config;
  config.particles = 20;
  config.resolution_m = 0.1;
  config.motion_noise = {0.04, 0.004, 0.02, 0.02};
  config.update_distance_m = 0.4;
  config.update_angle_rad = 0.4;
  return config;
}

TEST(PoseFilter, EndsNearerTheTruthThanDriftingOdometry) {
  for (const std::uint64_t seed : {1u, 2u, 3u}) {
    const DriveResult result = drive(seed, driveConfig());
    std::cout << "seed " << seed << ": mean position error filter " << result.filter_error_m << " m, odometry "
              << result.odometry_error_m << " m; at the end " << result.filter_final_m << " m, "
              << result.odometry_final_m << " m; " << result.resamplings << " resamplings\n";
    EXPECT_LT(result.filter_error_m, 0.5 * result.odometry_error_m)
        << "seed " << seed << ": filter " << result.filter_error_m << " m, odometry " << result.odometry_error_m << " m";
    EXPECT_LT(result.filter_final_m, 0.25) << "seed " << seed << " (odometry " << result.odometry_final_m << " m)";
  }
}

TEST(PoseFilter, ResultsDoNotDependOnTheThreads) {
  dog::PoseFilterConfig one = driveConfig();
  one.particles = 6;
  one.threads = 1;
  dog::PoseFilterConfig two = one;
  two.threads = 2;
  const DriveResult a = drive(7, one);
  EXPECT_GT(a.peak_map_bytes, 0u);
  const DriveResult b = drive(7, two);
  EXPECT_EQ(a.filter_error_m, b.filter_error_m);
  EXPECT_EQ(a.resamplings, b.resamplings);
}

TEST(PoseFilter, TrajectoryEntropyAndCorrection) {
  // Odometry exact, no noise, no matching: every particle follows odometry, so the best
  // trajectory is the updates' poses, the correction is the identity, and the particles
  // (all at one pose) have the entropy of the variance floor.
  const std::vector<Box> boxes = room();
  dog::PoseFilterConfig config;
  config.particles = 4;
  config.resolution_m = 0.1;
  config.motion_noise = {};
  config.scan_matching = false;
  dog::PoseFilter filter(config, std::make_shared<dog::UniformTransitions>(dog::TransitionParams{0.0, 0.0}));
  std::mt19937_64 rng(5);
  const std::vector<dog::Pose2D> poses = {{2.0, 2.0, 0.0}, {2.6, 2.0, 0.0}, {2.6, 2.0, 0.7}, {3.2, 2.4, 0.7}};
  for (std::size_t i = 0; i < poses.size(); ++i) {
    ASSERT_TRUE(filter.integrate(simulatedScan(boxes, poses[i], static_cast<double>(i), rng, 0.0)).updated) << i;
  }
  const std::vector<dog::TrajectoryNode> trajectory = filter.bestTrajectory();
  ASSERT_EQ(trajectory.size(), poses.size());
  for (std::size_t i = 0; i < poses.size(); ++i) {
    EXPECT_EQ(trajectory[i].stamp_s, static_cast<double>(i));
    expectPose(trajectory[i].pose, poses[i], 1e-9);
  }
  expectPose(filter.mapToOdometry(), dog::Pose2D{}, 1e-9);
  const double floor_entropy = 0.5 * std::log(std::pow(2.0 * kPi * std::exp(1.0), 3) * 1e-36);
  EXPECT_NEAR(filter.poseEntropy(), floor_entropy, 1e-6);
  EXPECT_NEAR(filter.effectiveSampleSize(), 4.0, 1e-9);
}

TEST(PoseFilter, BadConfigsAreRefused) {
  const auto transitions = std::make_shared<dog::UniformTransitions>(dog::TransitionParams{0.0, 0.0});
  const auto refused = [&](const std::function<void(dog::PoseFilterConfig&)>& change) {
    dog::PoseFilterConfig config;
    change(config);
    EXPECT_THROW(dog::PoseFilter(config, transitions), std::invalid_argument);
  };
  refused([](auto& c) { c.particles = 0; });
  refused([](auto& c) { c.update_distance_m = 0.0; });
  refused([](auto& c) { c.resample_below = 1.5; });
  refused([](auto& c) { c.resolution_m = std::nan(""); });
  refused([](auto& c) { c.p_hit_given_occ = 0.1; });
  refused([](auto& c) { c.unknown_p_occ = 1.0; });
  refused([](auto& c) { c.match_beam_stride = 0; });
  refused([](auto& c) { c.motion_noise.rot_from_rot = -1.0; });
  refused([](auto& c) { c.weight_beams = 0; });
  refused([](auto& c) { c.weight_sigma_m = 0.0; });
  refused([](auto& c) { c.weight_z_rand = 0.0; });
  refused([](auto& c) { c.weight_z_hit = -0.1; });
  refused([](auto& c) { c.weight_max_distance_m = 10.0; });  // 200 cells
  refused([](auto& c) { c.guard_sigmas = -1.0; });
  refused([](auto& c) { c.guard_window_m = std::nan(""); });
  refused([](auto& c) { c.correction_min_gain = std::nan(""); });
  EXPECT_THROW(dog::PoseFilter(dog::PoseFilterConfig{}, nullptr), std::invalid_argument);
  EXPECT_THROW(dog::UniformTransitions({1.5, 0.0}), std::invalid_argument);
  dog::PoseFilter filter(dog::PoseFilterConfig{}, transitions);
  EXPECT_THROW(filter.bestIndex(), std::logic_error);
  EXPECT_THROW(filter.integrate(dog::Scan{}), std::invalid_argument);  // no ranges
}

// --- mapping with corrected poses (core/pose/corrected_mapping.h) ---------------------------------

TEST(CorrectedMapping, ConfigTakesTheMappersMapAndSensor) {
  dog::MapperConfig mapper;
  mapper.resolution_m = 0.02;
  mapper.time_step_s = 0.5;
  mapper.p_hit_given_occ = 0.8;
  mapper.p_hit_given_free = 0.1;
  mapper.max_free_range_m = 7.0;
  dog::PoseFilterConfig filter;
  filter.particles = 7;
  const dog::PoseFilterConfig made = dog::poseFilterConfigFor(mapper, filter);
  EXPECT_EQ(made.particles, 7u);
  EXPECT_EQ(made.resolution_m, 0.02);
  EXPECT_EQ(made.time_step_s, 0.5);
  EXPECT_EQ(made.p_hit_given_occ, 0.8);
  EXPECT_EQ(made.p_hit_given_free, 0.1);
  EXPECT_EQ(made.max_free_range_m, 7.0);
  EXPECT_NEAR(made.max_range_m, 20.0, 1e-12);  // 1000 cells, below the default 30 m
  EXPECT_NO_THROW(made.validate());
}

TEST(CorrectedMapping, MapsAtOdometryUntilASettledMapAsksForACorrection) {
  // A drive of 15 s through CorrectedMapping started with a correction S, against the same
  // filter run alone on odometry moved by S (its frame is then the map frame) with a learner
  // fed the scans as mapped. No settled map (the map as it was 30 s ago) exists yet, so the
  // correction in use stays S: every scan is mapped at S times odometry, while the filter
  // runs as it would alone: the same updates and trajectory, and the same map, cell for
  // cell. The learner's transitions matter (one observed step makes a cell learned), so a
  // filter reading them at other cells than the map's would part from the reference.
  const std::vector<Box> boxes = room();
  dog::MapperConfig mapper_config;
  mapper_config.resolution_m = 0.1;
  mapper_config.prior_transitions = {0.05, 0.05};
  dog::Mapper mapper(mapper_config);
  dog::Mapper reference_learner(mapper_config);
  dog::PoseFilterConfig config = dog::poseFilterConfigFor(mapper_config, driveConfig());
  config.particles = 8;
  const dog::Pose2D start{1.0, -2.0, 0.5};
  dog::CorrectedMapping mapping(mapper, config, 1, start);
  expectPose(mapping.mapToOdometry(), start, 0.0);
  EXPECT_TRUE(mapping.trajectory().empty());
  dog::PoseFilter reference(config, std::make_shared<dog::MapperTransitions>(reference_learner, 0.1, 1));
  std::mt19937_64 rng(3);
  dog::Pose2D truth{2.0, 2.0, 0.0};  // in the room
  std::vector<dog::TrajectoryNode> expected_trajectory;
  bool filter_moved = false;
  for (int i = 0; i < 30; ++i) {
    truth = dog::applyMotion(truth, dog::OdometryMotion{0.05, 0.15, -0.02});
    dog::Scan scan = simulatedScan(boxes, truth, 0.5 * i, rng, 0.01);
    scan.laser_pose = dog::relativePose(start, truth);  // odometry: the truth seen from S
    const dog::CorrectedScan result = mapping.integrate(scan);
    ASSERT_EQ(result.mapped.status, dog::ScanStatus::kIntegrated) << result.mapped.error;
    dog::Scan shifted = scan;
    shifted.laser_pose = truth;  // S times odometry
    const dog::PoseUpdate update = reference.integrate(shifted);
    EXPECT_EQ(result.update.updated, update.updated) << i;
    expectPose(result.corrected.laser_pose, truth, 1e-9);
    expectPose(mapping.mapToOdometry(), start, 1e-9);
    expectPose(mapping.filter().mapToOdometry(), reference.mapToOdometry(), 1e-9);
    const dog::Pose2D filters = reference.mapToOdometry();
    filter_moved = filter_moved || filters.x_m != 0.0 || filters.y_m != 0.0 || filters.yaw_rad != 0.0;
    if (update.updated) expected_trajectory.push_back({scan.stamp_s, truth});
    reference_learner.integrate(result.corrected);
  }
  EXPECT_GT(mapping.filter().updates(), 5u);
  EXPECT_TRUE(filter_moved);  // the filter did correct: the correction in use held against it
  EXPECT_EQ(mapping.correctionsTaken(), 0u);
  const std::vector<dog::TrajectoryNode> filters = reference.bestTrajectory();
  const std::vector<dog::TrajectoryNode> lineage = mapping.filter().bestTrajectory();
  ASSERT_EQ(lineage.size(), filters.size());
  for (std::size_t i = 0; i < lineage.size(); ++i) {
    EXPECT_EQ(lineage[i].stamp_s, filters[i].stamp_s);
    expectPose(lineage[i].pose, filters[i].pose, 1e-9);
  }
  const std::vector<dog::TrajectoryNode> trajectory = mapping.trajectory();
  ASSERT_EQ(trajectory.size(), expected_trajectory.size());
  for (std::size_t i = 0; i < trajectory.size(); ++i) {
    EXPECT_EQ(trajectory[i].stamp_s, expected_trajectory[i].stamp_s);
    expectPose(trajectory[i].pose, expected_trajectory[i].pose, 1e-9);
  }
  mapper.finishStep();
  reference_learner.finishStep();
  const dog::CellBox box = mapper.grid().bounds();
  const dog::CellBox reference_box = reference_learner.grid().bounds();
  EXPECT_EQ(box.min_x, reference_box.min_x);
  EXPECT_EQ(box.min_y, reference_box.min_y);
  EXPECT_EQ(box.width(), reference_box.width());
  EXPECT_EQ(box.height(), reference_box.height());
  std::size_t compared = 0;
  for (std::int32_t y = box.min_y; y <= box.max_y; ++y) {
    for (std::int32_t x = box.min_x; x <= box.max_x; ++x) {
      const auto cell = mapper.grid().cell(x, y);
      if (!cell || cell->last_step == dog::kNeverObserved) continue;
      ASSERT_EQ(mapper.beliefAt(x, y, 20), reference_learner.beliefAt(x, y, 20)) << x << ", " << y;
      ++compared;
    }
  }
  EXPECT_GT(compared, 1000u);
}

// The farthest the scan's laser position and beam ends lie apart in the map under the
// corrections (map -> odom) a and b.
double farthestMove(const dog::Pose2D& a, const dog::Pose2D& b, const dog::Scan& scan) {
  double farthest = 0.0;
  const auto move = [&](const dog::Pose2D& point) {
    const dog::Pose2D in_a = dog::composePose(a, point);
    const dog::Pose2D in_b = dog::composePose(b, point);
    farthest = std::max(farthest, std::hypot(in_a.x_m - in_b.x_m, in_a.y_m - in_b.y_m));
  };
  move(scan.laser_pose);
  for (std::size_t i = 0; i < scan.ranges_m.size(); ++i) {
    const double range = scan.ranges_m[i];
    if (!(range >= scan.range_min_m && range <= scan.range_max_m)) continue;
    const double angle = scan.angle_min_rad + static_cast<double>(i) * scan.angle_increment_rad;
    move(dog::composePose(scan.laser_pose, dog::Pose2D{range * std::cos(angle), range * std::sin(angle), 0.0}));
  }
  return farthest;
}

struct CorrectedDrive {
  std::size_t taken = 0;
  double first_taken_s = -1.0;
  std::size_t remapped = 0;       ///< scans mapped again, over all corrections
  double odometry_error_m = 0.0;  ///< mean position error over the last lap, at the filter's updates
  double mapped_error_m = 0.0;    ///< of the poses the scans were mapped at when they came
  double final_error_m = 0.0;     ///< of the poses they were mapped at in the end
};

// `laps` laps of drive()'s loop (0.2 m and 0.5 s a scan: 40 s a lap) through CorrectedMapping,
// odometry drifting by `drift`. Checks on the way that the correction in use changes only to
// the filter's, by more than two cells (0.2 m), and that every scan is mapped at it; where
// a change maps the last `remapped` scans again, computes their poses itself (each scan's
// correction plus the change times its share of the laser's travel in odometry since the
// last change, the first of them or 10 m back, whichever is nearest: path plus turns at 1 m
// per radian). At the end the Mapper must be, cell for
// cell, a Mapper fed every scan at those poses, and trajectory() must hold them.
CorrectedDrive correctedDrive(std::uint64_t seed, const dog::OdometryNoise& drift, int laps) {
  const std::vector<Box> boxes = room();
  const std::vector<dog::Pose2D> truth = loopLaps(laps);
  dog::MapperConfig mapper_config;
  mapper_config.resolution_m = 0.1;
  dog::Mapper mapper(mapper_config);
  dog::SequenceBuilder recorder;  // for offline EM: recorded again where scans are mapped again
  mapper.recordObservations(&recorder);
  dog::CorrectedMapping mapping(mapper, dog::poseFilterConfigFor(mapper_config, driveConfig()), 1);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal;
  CorrectedDrive result;
  dog::Pose2D odometry = truth[0];
  std::size_t last_lap_updates = 0;
  const auto wrapped = [](dog::Pose2D pose) {
    pose.yaw_rad = std::remainder(pose.yaw_rad, 2.0 * kPi);
    return pose;
  };
  std::vector<dog::Scan> scans;           // at odometry, the yaw wrapped (as the filter sees it)
  std::vector<double> travel;             // the laser's, in odometry, up to each scan
  std::vector<dog::Pose2D> corrections;   // each scan is mapped at, as of now
  std::vector<bool> updated;
  std::optional<std::size_t> last_taken;  // the scan that changed the correction in use last
  for (std::size_t i = 0; i < truth.size(); ++i) {
    if (i > 0) {
      odometry = dog::applyMotion(odometry, dog::perturbMotion(dog::odometryMotion(truth[i - 1], truth[i]), drift,
                                                               {normal(rng), normal(rng), normal(rng)}));
    }
    dog::Scan scan = simulatedScan(boxes, truth[i], 0.5 * static_cast<double>(i), rng, 0.01);
    scan.laser_pose = odometry;
    const dog::Pose2D seen = wrapped(odometry);
    travel.push_back(i == 0 ? 0.0
                            : travel.back() + (std::hypot(seen.x_m - scans.back().laser_pose.x_m,
                                                          seen.y_m - scans.back().laser_pose.y_m) +
                                               1.0 * std::abs(std::remainder(
                                                         seen.yaw_rad - scans.back().laser_pose.yaw_rad, 2.0 * kPi))));
    scans.push_back(scan);
    scans.back().laser_pose = seen;
    const dog::Pose2D before = mapping.mapToOdometry();
    const dog::CorrectedScan corrected = mapping.integrate(scan);
    EXPECT_EQ(corrected.mapped.status, dog::ScanStatus::kIntegrated) << corrected.mapped.error;
    const dog::Pose2D now = mapping.mapToOdometry();
    expectPose(corrected.corrected.laser_pose, dog::composePose(now, odometry), 1e-9);
    corrections.push_back(now);
    updated.push_back(corrected.update.updated);
    if (now.x_m != before.x_m || now.y_m != before.y_m || now.yaw_rad != before.yaw_rad) {
      ++result.taken;
      if (result.first_taken_s < 0.0) result.first_taken_s = scan.stamp_s;
      EXPECT_TRUE(corrected.update.updated) << i;
      expectPose(now, mapping.filter().mapToOdometry(), 0.0);
      EXPECT_GT(farthestMove(before, now, scan), 0.2) << i;
      // The scans mapped again: from the first's correction to this one's, by travel.
      EXPECT_LE(corrected.remapped, i);
      EXPECT_LE(0.5 * static_cast<double>(corrected.remapped), 61.0) << "at most 60 s back";
      if (corrected.remapped > 0) {
        const std::size_t first = i - corrected.remapped;
        const double start = std::max({travel[first], last_taken ? travel[*last_taken] : 0.0, travel[i] - 10.0});
        const double span = travel[i] - start;
        const double dyaw = std::remainder(now.yaw_rad - before.yaw_rad, 2.0 * kPi);
        for (std::size_t j = first; j < i; ++j) {
          const double f = span > 0.0 ? std::clamp((travel[j] - start) / span, 0.0, 1.0) : 1.0;
          corrections[j] = wrapped({corrections[j].x_m + f * (now.x_m - before.x_m),
                                    corrections[j].y_m + f * (now.y_m - before.y_m), corrections[j].yaw_rad + f * dyaw});
        }
      }
      last_taken = i;
    } else {
      EXPECT_EQ(corrected.remapped, 0u) << i;
    }
    result.remapped += corrected.remapped;
    if (corrected.update.updated && static_cast<int>(i) * laps >= (laps - 1) * static_cast<int>(truth.size())) {
      const dog::Pose2D& mapped = corrected.corrected.laser_pose;
      result.mapped_error_m += std::hypot(mapped.x_m - truth[i].x_m, mapped.y_m - truth[i].y_m);
      result.odometry_error_m += std::hypot(odometry.x_m - truth[i].x_m, odometry.y_m - truth[i].y_m);
      ++last_lap_updates;
    }
  }
  mapping.finish();
  EXPECT_EQ(mapping.correctionsTaken(), result.taken);
  EXPECT_EQ(mapping.scansRemapped(), result.remapped);
  result.mapped_error_m /= static_cast<double>(last_lap_updates);
  result.odometry_error_m /= static_cast<double>(last_lap_updates);
  // The Mapper is the scans at the poses as of now, and so is what it recorded; so is the
  // trajectory at the updates.
  dog::Mapper reference(mapper_config);
  dog::SequenceBuilder reference_recorder;
  reference.recordObservations(&reference_recorder);
  const std::vector<dog::TrajectoryNode> trajectory = mapping.trajectory();
  std::size_t node = 0;
  for (std::size_t i = 0; i < scans.size(); ++i) {
    dog::Scan scan = scans[i];
    scan.laser_pose = wrapped(dog::composePose(corrections[i], scans[i].laser_pose));
    reference.integrate(scan);
    if (!updated[i]) continue;
    EXPECT_LT(node, trajectory.size());
    if (node >= trajectory.size()) break;
    expectPose(trajectory[node].pose, scan.laser_pose, 1e-9);
    if (static_cast<int>(i) * laps >= (laps - 1) * static_cast<int>(truth.size())) {
      result.final_error_m += std::hypot(scan.laser_pose.x_m - truth[i].x_m, scan.laser_pose.y_m - truth[i].y_m);
    }
    ++node;
  }
  EXPECT_EQ(node, trajectory.size());
  result.final_error_m /= static_cast<double>(last_lap_updates);
  mapper.finishStep();
  reference.finishStep();
  EXPECT_EQ(dog::serializeModel(mapper), dog::serializeModel(reference));
  const dog::ObservationSequences recorded = recorder.build();
  const dog::ObservationSequences expected = reference_recorder.build();
  EXPECT_GT(expected.observationCount(), 0u);
  EXPECT_EQ(recorded.observationCount(), expected.observationCount());
  EXPECT_EQ(recorded.cellCount(), expected.cellCount());
  std::map<std::pair<std::int32_t, std::int32_t>, std::vector<std::array<std::int64_t, 3>>> by_cell[2];
  for (int k = 0; k < 2; ++k) {
    const dog::ObservationSequences& sequences = k == 0 ? recorded : expected;
    for (std::size_t c = 0; c < sequences.cellCount(); ++c) {
      auto& list = by_cell[k][{sequences.cell(c).x, sequences.cell(c).y}];
      for (const auto* o = sequences.begin(c); o != sequences.end(c); ++o) list.push_back({o->step, o->hits, o->misses});
    }
  }
  EXPECT_TRUE(by_cell[0] == by_cell[1]) << "the recorded observations differ";
  return result;
}

TEST(CorrectedMapping, TakesTheFiltersCorrectionWhereTheSettledMapShowsDrift) {
  // Drifting odometry, three laps: from the second on the scans see the map as it was a lap
  // ago, and the filter's correction is taken; over the last lap the scans are mapped
  // nearer the truth than odometry has them.
  for (const std::uint64_t seed : {1u}) {
    const CorrectedDrive result = correctedDrive(seed, dog::OdometryNoise{0.02, 0.002, 0.01, 0.01}, 3);
    std::cout << "seed " << seed << ": " << result.taken << " corrections taken, the first at " << result.first_taken_s
              << " s, " << result.remapped << " scans mapped again; last lap's mean position error: mapped "
              << result.mapped_error_m << " m (in the end " << result.final_error_m << " m), odometry "
              << result.odometry_error_m << " m\n";
    EXPECT_GT(result.taken, 0u);
    EXPECT_GE(result.first_taken_s, 30.0);  // no settled map before
    EXPECT_GT(result.remapped, 0u);
    EXPECT_LT(result.mapped_error_m, 0.5 * result.odometry_error_m);
    EXPECT_LT(result.final_error_m, 0.5 * result.odometry_error_m);
  }
}

TEST(CorrectedMapping, SettingsChangedWhileMappingAgainKeepTheMapAsItCame) {
  // The drift of TakesTheFiltersCorrection...: at the first correction taken the mapper's
  // settings change (the node's dynamic_reconfigure), so the scans mapped again from the
  // checkpoint, which holds the old ones, are not taken 5 s later: the Mapper is every scan
  // at the pose it had when it came. A CorrectedMapping left with a re-mapping running
  // (the second drive stops at the correction) waits for it when it goes.
  const std::vector<Box> boxes = room();
  const std::vector<dog::Pose2D> truth = loopLaps(2);
  dog::MapperConfig mapper_config;
  mapper_config.resolution_m = 0.1;
  for (const bool stop_at_the_correction : {false, true}) {
    dog::Mapper mapper(mapper_config);
    dog::Mapper reference(mapper_config);
    auto mapping = std::make_unique<dog::CorrectedMapping>(
        mapper, dog::poseFilterConfigFor(mapper_config, driveConfig()), 1);
    std::mt19937_64 rng(1);
    std::normal_distribution<double> normal;
    dog::Pose2D odometry = truth[0];
    std::optional<double> taken_s;
    for (std::size_t i = 0; i < truth.size(); ++i) {
      if (i > 0) {
        odometry = dog::applyMotion(odometry, dog::perturbMotion(dog::odometryMotion(truth[i - 1], truth[i]),
                                                                 dog::OdometryNoise{0.02, 0.002, 0.01, 0.01},
                                                                 {normal(rng), normal(rng), normal(rng)}));
      }
      dog::Scan scan = simulatedScan(boxes, truth[i], 0.5 * static_cast<double>(i), rng, 0.01);
      scan.laser_pose = odometry;
      const dog::CorrectedScan corrected = mapping->integrate(scan);
      reference.integrate(corrected.corrected);
      if (corrected.remapped > 0 && !taken_s) {
        taken_s = scan.stamp_s;
        if (stop_at_the_correction) break;
        mapper.setLearnTransitions(true);  // as it was: only the revision changes
        reference.setLearnTransitions(true);
      }
      if (taken_s && scan.stamp_s > *taken_s + 10.0) break;
    }
    ASSERT_TRUE(taken_s.has_value());
    if (stop_at_the_correction) {
      mapping.reset();  // waits for the re-mapping, takes nothing
      continue;
    }
    mapping->finish();
    mapper.finishStep();
    reference.finishStep();
    EXPECT_EQ(dog::serializeModel(mapper), dog::serializeModel(reference));
  }
}

TEST(CorrectedMapping, ARemappingTakenBetweenScansGivesTheMapTheNextScanWould) {
  // The drift of TakesTheFiltersCorrection...: one run takes each re-mapping as the next
  // scan does; the other takes it right after the scan that started it, before the next
  // (the node's publish timer, takeFinishedRemap, waiting for it to end; or a service,
  // finish()). The same Mapper, trajectory and corrections in the end.
  const std::vector<Box> boxes = room();
  const std::vector<dog::Pose2D> truth = loopLaps(3);
  dog::MapperConfig mapper_config;
  mapper_config.resolution_m = 0.1;
  struct Run {
    std::string model;
    std::vector<dog::TrajectoryNode> trajectory;
    std::size_t taken = 0;
    std::size_t between_scans = 0;
  };
  const auto drive = [&](bool between_scans) {
    dog::Mapper mapper(mapper_config);
    dog::CorrectedMapping mapping(mapper, dog::poseFilterConfigFor(mapper_config, driveConfig()), 1);
    std::mt19937_64 rng(1);
    std::normal_distribution<double> normal;
    dog::Pose2D odometry = truth[0];
    Run run;
    for (std::size_t i = 0; i < truth.size(); ++i) {
      if (i > 0) {
        odometry = dog::applyMotion(odometry, dog::perturbMotion(dog::odometryMotion(truth[i - 1], truth[i]),
                                                                 dog::OdometryNoise{0.02, 0.002, 0.01, 0.01},
                                                                 {normal(rng), normal(rng), normal(rng)}));
      }
      dog::Scan scan = simulatedScan(boxes, truth[i], 0.5 * static_cast<double>(i), rng, 0.01);
      scan.laser_pose = odometry;
      const dog::CorrectedScan corrected = mapping.integrate(scan);
      if (between_scans && corrected.remapped > 0) {
        if (run.between_scans % 2 == 0) {
          while (!mapping.takeFinishedRemap()) std::this_thread::yield();
        } else {
          mapping.finish();
        }
        EXPECT_FALSE(mapping.takeFinishedRemap());  // nothing left running
        ++run.between_scans;
      }
    }
    mapping.finish();
    mapper.finishStep();
    run.model = dog::serializeModel(mapper);
    run.trajectory = mapping.trajectory();
    run.taken = mapping.correctionsTaken();
    return run;
  };
  const Run at_next_scan = drive(false);
  const Run between = drive(true);
  ASSERT_GE(between.between_scans, 2u);  // both ways taken
  EXPECT_EQ(between.taken, at_next_scan.taken);
  EXPECT_TRUE(between.model == at_next_scan.model);
  ASSERT_EQ(between.trajectory.size(), at_next_scan.trajectory.size());
  for (std::size_t i = 0; i < between.trajectory.size(); ++i) {
    EXPECT_EQ(between.trajectory[i].pose.x_m, at_next_scan.trajectory[i].pose.x_m) << i;
    EXPECT_EQ(between.trajectory[i].pose.y_m, at_next_scan.trajectory[i].pose.y_m) << i;
    EXPECT_EQ(between.trajectory[i].pose.yaw_rad, at_next_scan.trajectory[i].pose.yaw_rad) << i;
  }
}

TEST(CorrectedMapping, PerfectOdometryIsNeverCorrected) {
  // Odometry without error, two laps (a settled map from 30 s on): the settled map agrees
  // with it, so whatever the filter's particles make of the scans, map -> odom stays where
  // it started.
  const CorrectedDrive result = correctedDrive(5, dog::OdometryNoise{0.0, 0.0, 0.0, 0.0}, 2);
  EXPECT_EQ(result.taken, 0u);
  EXPECT_EQ(result.remapped, 0u);
  EXPECT_EQ(result.mapped_error_m, 0.0);
  EXPECT_EQ(result.final_error_m, 0.0);
}

TEST(PoseFilter, BestAfterResamplingIsTheBestBefore) {
  // One update, resampled or not: the same draws before resampling, so the best particle
  // after resampling has the pose of the one with the highest weight without it.
  const std::vector<Box> boxes = room();
  dog::PoseFilterConfig kept = driveConfig();
  kept.particles = 12;
  kept.resample_below = 0.0;
  dog::PoseFilterConfig resampled = kept;
  resampled.resample_below = 1.0;
  const auto transitions = std::make_shared<dog::UniformTransitions>(dog::TransitionParams{0.0, 0.0});
  dog::PoseFilter a(kept, transitions);
  dog::PoseFilter b(resampled, transitions);
  std::mt19937_64 rng(11);
  const dog::Scan first = simulatedScan(boxes, {2.0, 2.0, 0.0}, 0.0, rng, 0.01);
  dog::Scan second = simulatedScan(boxes, {2.6, 2.1, 0.1}, 1.0, rng, 0.01);
  second.laser_pose = {2.5, 2.0, 0.0};  // odometry a little off
  for (dog::PoseFilter* filter : {&a, &b}) {
    filter->integrate(first);
    ASSERT_TRUE(filter->integrate(second).updated);
  }
  EXPECT_EQ(b.resamplings(), 1u);
  EXPECT_EQ(a.resamplings(), 0u);
  expectPose(b.best().pose, a.best().pose, 0.0);
  expectPose(b.mapToOdometry(), a.mapToOdometry(), 0.0);
}

TEST(CorrectedMapping, TheModelFileHoldsTheBestParticlesMap) {
  // A drive with a restart halfway (a new filter on the same Mapper, as the node's ~reset
  // of the correction or a loaded model: its first scan is 0.4 of a step into the Mapper's
  // step) and a Mapper lattice 50 (or 50.3) cells off the filter's. The saved model must
  // hold, in each cell the best particle has observed by the Mapper's last update of it,
  // the particle's belief; in every other cell the Mapper's; the learner's state split over
  // the state now by the saved belief, each part keeping its mass; the rest of every cell
  // unchanged. With every cell's transitions in use (gate 1) the saved belief is compared
  // with the particle's at a later step, each predicted its own way; with a gate of 3
  // observed steps (cells seen less are static to the filter) at the cell's last step.
  struct Run {
    dog::TransitionLearner learner;
    std::uint32_t min_observed_steps;
    double origin_m;
  };
  for (const Run run : {Run{dog::TransitionLearner::kCellEm, 1, -5.0}, Run{dog::TransitionLearner::kKinds, 1, -5.0},
                        Run{dog::TransitionLearner::kCellEm, 3, -5.03}}) {
    const dog::TransitionLearner learner = run.learner;
    SCOPED_TRACE(std::string(learner == dog::TransitionLearner::kKinds ? "kinds" : "cell_em") + ", gate " +
                 std::to_string(run.min_observed_steps));
    const std::vector<Box> boxes = room();
    dog::MapperConfig mapper_config;
    mapper_config.resolution_m = 0.1;
    mapper_config.time_step_s = 1.0;
    mapper_config.origin_x_m = run.origin_m;
    mapper_config.origin_y_m = run.origin_m;
    mapper_config.prior_transitions = {0.05, 0.05};
    mapper_config.learner = learner;
    dog::Mapper mapper(mapper_config);
    dog::PoseFilterConfig config = dog::poseFilterConfigFor(mapper_config, driveConfig());
    config.particles = 8;
    auto mapping = std::make_unique<dog::CorrectedMapping>(mapper, config, run.min_observed_steps);
    EXPECT_EQ(mapping->serializeModel(), dog::serializeModel(mapper));  // nothing mapped yet
    std::mt19937_64 rng(5);
    dog::Pose2D truth{2.0, 2.0, 0.0};
    constexpr int kRestart = 18;
    const double restart_stamp = 0.3 * kRestart + 0.1;
    for (int i = 0; i < 36; ++i) {
      if (i == kRestart) {
        mapping = std::make_unique<dog::CorrectedMapping>(mapper, config, run.min_observed_steps, mapping->mapToOdometry());
      }
      truth = dog::applyMotion(truth, dog::OdometryMotion{0.05, 0.15, -0.02});
      const dog::CorrectedScan result = mapping->integrate(simulatedScan(boxes, truth, 0.3 * i + 0.1, rng, 0.01));
      ASSERT_EQ(result.mapped.status, dog::ScanStatus::kIntegrated) << result.mapped.error;
    }
    mapper.finishStep();
    // The filter's steps are the Mapper's moved by the Mapper's step of the restart.
    const std::int64_t offset = mapper.clock().stepOf(restart_stamp);
    ASSERT_EQ(offset, 5);
    EXPECT_NEAR(*mapping->filter().clock().origin(), mapper.clock().stepStart(offset), 1e-9);

    dog::BestParticleCells cells;
    const std::unique_ptr<dog::Mapper> loaded = dog::deserializeModel(mapping->serializeModel(&cells));
    const std::int64_t later = *mapper.lastAppliedStep() + 3;
    const dog::ParticleMap& map = mapping->filter().best().map;
    const dog::TransitionSource& transitions = mapping->filter().transitions();
    std::size_t replaced = 0;
    std::size_t kept = 0;
    std::size_t differ = 0;
    const dog::CellBox box = mapper.grid().bounds();
    for (std::int32_t y = box.min_y; y <= box.max_y; ++y) {
      for (std::int32_t x = box.min_x; x <= box.max_x; ++x) {
        const auto cell = mapper.grid().cell(x, y);
        if (!cell || cell->last_step == dog::kNeverObserved) continue;
        const auto saved = loaded->grid().cell(x, y);
        ASSERT_TRUE(saved.has_value()) << x << ", " << y;
        EXPECT_EQ(saved->last_step, cell->last_step);
        EXPECT_EQ(saved->log_odds, cell->log_odds);
        EXPECT_EQ(saved->p_occ_given_free, cell->p_occ_given_free);
        EXPECT_EQ(saved->p_free_given_occ, cell->p_free_given_occ);
        EXPECT_EQ(saved->observed_steps, cell->observed_steps);
        // The filter's cell holding this cell's centre (the lattices' corners differ by 50 or
        // 50.3 cells).
        const auto px = static_cast<std::int32_t>(std::floor((run.origin_m + (x + 0.5) * 0.1) / 0.1));
        const auto py = static_cast<std::int32_t>(std::floor((run.origin_m + (y + 0.5) * 0.1) / 0.1));
        ASSERT_EQ(px, x - 50);
        const std::int32_t particle_step = map.lastStep(px, py);
        const bool from_particle = particle_step != dog::kNeverObserved && particle_step <= cell->last_step - offset;
        if (from_particle) {
          ++replaced;
          if (run.min_observed_steps == 1) {
            const double particle = map.predicted(px, py, later - offset, transitions, 0.5);
            ASSERT_NEAR(loaded->beliefAt(x, y, later), particle, 1e-5) << x << ", " << y;
            differ += std::abs(particle - mapper.beliefAt(x, y, later)) > 1e-3 ? 1 : 0;
          } else {
            const double particle = map.predicted(px, py, cell->last_step - offset, transitions, 0.5);
            ASSERT_FLOAT_EQ(saved->p_occ, static_cast<float>(particle)) << x << ", " << y;
            differ += std::abs(particle - cell->p_occ) > 1e-3 ? 1 : 0;
          }
          // The learner's state: each kind, or each past transition i -> j, keeps its mass,
          // split over the state now by the saved belief.
          const int pairs = learner == dog::TransitionLearner::kKinds ? dog::kKindCount : 4;
          for (int k = 0; k < pairs; ++k) {
            const double mass = double{cell->em_stats[2 * k]} + cell->em_stats[2 * k + 1];
            EXPECT_NEAR(saved->em_stats[2 * k] + saved->em_stats[2 * k + 1], mass, 1e-5 * std::max(1.0, mass));
            EXPECT_NEAR(saved->em_stats[2 * k], mass * saved->p_occ, 1e-5 * std::max(1.0, mass));
          }
        } else {
          ++kept;
          ASSERT_EQ(loaded->beliefAt(x, y, later), mapper.beliefAt(x, y, later)) << x << ", " << y;
          EXPECT_EQ(saved->em_stats, cell->em_stats);
        }
      }
    }
    // The best particle's map as the node publishes it, now and 7 steps ahead: the window
    // of its tiles, each cell predicted from the particle's own state, NaN where unseen.
    EXPECT_THROW(mapping->bestParticleBelief(-1), std::invalid_argument);
    for (const std::int64_t horizon : {std::int64_t{0}, std::int64_t{7}}) {
      const dog::ParticleBelief belief = mapping->bestParticleBelief(horizon);
      const dog::CellBox tiles = map.bounds();
      EXPECT_EQ(belief.window.cells.min_x, tiles.min_x);
      EXPECT_EQ(belief.window.cells.max_y, tiles.max_y);
      EXPECT_DOUBLE_EQ(belief.window.origin_x_m, tiles.min_x * 0.1);
      ASSERT_EQ(belief.values.size(), static_cast<std::size_t>(tiles.width() * tiles.height()));
      std::size_t seen = 0;
      for (std::int32_t y = tiles.min_y; y <= tiles.max_y; ++y) {
        for (std::int32_t x = tiles.min_x; x <= tiles.max_x; ++x) {
          const float value = belief.values[static_cast<std::size_t>((y - tiles.min_y) * tiles.width() + (x - tiles.min_x))];
          if (map.lastStep(x, y) == dog::kNeverObserved) {
            EXPECT_TRUE(std::isnan(value));
            continue;
          }
          ++seen;
          const std::int64_t step = mapping->filter().lastUpdateStep() + horizon;
          ASSERT_FLOAT_EQ(value, static_cast<float>(map.predicted(x, y, step, mapping->filter().transitions(), 0.5)));
        }
      }
      EXPECT_GT(seen, 1000u);
    }
    std::cout << "model cells: " << replaced << " from the best particle (" << differ << " differing from the "
              << "Mapper's by > 0.001), " << kept << " the Mapper's\n";
    EXPECT_EQ(cells.replaced, replaced);
    EXPECT_EQ(cells.kept, kept);
    EXPECT_GT(replaced, 1000u);
    EXPECT_GT(kept, 100u);   // seen before the restart only, or at other poses
    EXPECT_GT(differ, 100u);  // the Mapper maps every scan, the filter at its updates only
  }
}

TEST(CorrectedMapping, ABeliefOutsideZeroOneIsNotSaved) {
  dog::MapperConfig mapper_config;
  mapper_config.resolution_m = 0.1;
  dog::Mapper mapper(mapper_config);
  std::mt19937_64 rng(1);
  mapper.integrate(simulatedScan(room(), {2.0, 2.0, 0.0}, 0.0, rng, 0.0));
  mapper.finishStep();
  for (const float bad : {-0.1f, 1.5f, std::numeric_limits<float>::quiet_NaN()}) {
    EXPECT_THROW(dog::serializeModel(mapper, [bad](std::int32_t, std::int32_t, std::int32_t) { return bad; }),
                 std::invalid_argument);
  }
  EXPECT_EQ(dog::serializeModel(mapper, [](std::int32_t, std::int32_t, std::int32_t) { return std::nullopt; }),
            dog::serializeModel(mapper));
}

TEST(PoseFilter, StepsStartWhereTheyAreTold) {
  dog::PoseFilterConfig config = driveConfig();
  config.time_step_s = 1.0;
  const auto transitions = std::make_shared<dog::UniformTransitions>(dog::TransitionParams{0.0, 0.0});
  std::mt19937_64 rng(2);
  const dog::Scan first = simulatedScan(room(), {2.0, 2.0, 0.0}, 10.7, rng, 0.01);
  dog::PoseFilter outside(config, transitions);
  outside.startStepsAt(9.5);  // 10.7 is in step 1
  EXPECT_THROW(outside.integrate(first), std::invalid_argument);
  outside.startStepsAt(10.8);  // after the stamp
  EXPECT_THROW(outside.integrate(first), std::invalid_argument);
  outside.startStepsAt(10.5);  // replaces the earlier origins
  outside.integrate(first);
  EXPECT_EQ(*outside.clock().origin(), 10.5);
  // A first scan refused (a laser beyond any lattice) leaves the filter unstarted, its
  // clock too: a later first scan in another step starts it.
  dog::PoseFilter untold(config, transitions);
  dog::Scan far = first;
  far.laser_pose.x_m = 2.0e9;
  EXPECT_THROW(untold.integrate(far), std::invalid_argument);
  EXPECT_FALSE(untold.started());
  EXPECT_FALSE(untold.clock().origin().has_value());
  dog::Scan later_first = first;
  later_first.stamp_s = 15.0;
  untold.integrate(later_first);
  EXPECT_EQ(*untold.clock().origin(), 15.0);
  dog::PoseFilter filter(config, transitions);
  filter.startStepsAt(10.0);
  filter.integrate(first);
  EXPECT_EQ(*filter.clock().origin(), 10.0);
  EXPECT_THROW(filter.startStepsAt(10.5), std::logic_error);
  dog::Scan second = simulatedScan(room(), {2.6, 2.0, 0.0}, 12.2, rng, 0.01);
  ASSERT_TRUE(filter.integrate(second).updated);
  EXPECT_EQ(filter.lastUpdateStep(), 2);  // 12.2 from 10.0; from the stamp 10.7 it would be 1
}

TEST(CorrectedMapping, AScanTheFilterRefusesChangesNothing) {
  dog::MapperConfig mapper_config;
  mapper_config.resolution_m = 0.1;
  dog::Mapper mapper(mapper_config);
  dog::CorrectedMapping mapping(mapper, dog::poseFilterConfigFor(mapper_config, driveConfig()), 3);
  EXPECT_THROW(mapping.integrate(dog::Scan{}), std::invalid_argument);
  EXPECT_FALSE(mapper.clock().origin().has_value());
  EXPECT_FALSE(mapping.filter().started());
}

}  // namespace
