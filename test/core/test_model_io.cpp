// Tests of the model file (core/layers/model_io.h, docs/model_format.md): a saved and loaded
// Mapper is the same Mapper (every cell bit for bit, the configuration field by field, the
// time, the kinds of cells' sums), and it goes on mapping exactly as the original does, with
// either transition learner; the file's bytes are the ones documented; files of versions 1
// and 2 (built here from version 3 bytes) read as maps of each cell's online EM; every
// damaged file (any truncation, any single flipped byte, other versions, bad values, bad
// kinds, trailing bytes, absurd counts) is refused with a clear std::runtime_error; the
// file is replaced atomically and errors name it; what is not a regular file (a FIFO, a
// device, a directory) is refused before anything is read or replaced, and a file is read
// no further than its header promises.
//
// The checksum is checked against a bit-by-bit CRC-32 written here, independent of the
// zlib the library calls (the file promises the CRC-32 of zlib, which the Python reader
// uses too).

#include "dynamic_occupancy_grid/core/layers/model_io.h"

#include <gtest/gtest.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <sys/types.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace dog = dynamic_occupancy_grid::core;
namespace fs = std::filesystem;

namespace {

using XY = std::pair<std::int32_t, std::int32_t>;

constexpr double kPi = 3.14159265358979323846;
constexpr double kInf = std::numeric_limits<double>::infinity();

// Offsets of docs/model_format.md.
constexpr std::size_t kVersionOffset = 8;
constexpr std::size_t kResolutionOffset = 12;
constexpr std::size_t kPHitGivenOccOffset = 28;
constexpr std::size_t kLearnOffset = 60;
constexpr std::size_t kSymmetricOffset = 93;
constexpr std::size_t kMinObservedOffset = 94;
constexpr std::size_t kInitialPOccOffset = 98;
constexpr std::size_t kFixedOffset = 146;
constexpr std::size_t kMaxMapSizeOffset = 163;
constexpr std::size_t kHasOriginOffset = 171;
constexpr std::size_t kOriginOffset = 172;
constexpr std::size_t kHasLastStepOffset = 180;
constexpr std::size_t kLastStepOffset = 181;
// Version 2's learners' block follows the time.
constexpr std::size_t kLearnPriorOffset = 189;
constexpr std::size_t kScheduleOffset = 198;
constexpr std::size_t kLearnSensorOffset = 219;
constexpr std::size_t kSensorStatsOffset = 236;
// Version 3's block follows: the transition learner and the kinds of cells; then the cell count.
constexpr std::size_t kLearnerOffset = 268;
constexpr std::size_t kKindCountOffset = 269;
constexpr std::size_t kKindInitialTransitionsOffset = 270;  // per kind p_occ_given_free, p_free_given_occ
constexpr std::size_t kKindInitialWeightsOffset = 350;
constexpr std::size_t kKindTransitionPriorWeightOffset = 390;
constexpr std::size_t kKindWeightPriorCellsOffset = 398;
constexpr std::size_t kKindSwitchProbabilityOffset = 406;
constexpr std::size_t kKindForgettingOffset = 414;
constexpr std::size_t kKindSummaryOffset = 422;
constexpr std::size_t kKindCountingOffset = 423;
constexpr std::size_t kKindLearnFromGapsOffset = 424;
constexpr std::size_t kKindBinCountOffset = 425;  // u16
constexpr std::size_t kKindPairsOffset = 427;     // [kind][bin][2 i + j] (i: state then, j: now)
constexpr std::size_t kKindBins = 124;            // core/cell/cell_kinds.h kGapBins
constexpr std::size_t kKindPairsSize = 5 * kKindBins * 4 * 8;
constexpr std::size_t kKindMembershipOffset = kKindPairsOffset + kKindPairsSize;
constexpr std::size_t kKindCellsOffset = kKindMembershipOffset + 5 * 8;
constexpr std::size_t kKindTransitionsOffset = kKindCellsOffset + 8;  // per kind p_occ_given_free, p_free_given_occ
constexpr std::size_t kCountOffset = kKindTransitionsOffset + 5 * 16;
constexpr std::size_t kCellsOffset = kCountOffset + 8;
static_assert(kKindMembershipOffset == 20267 && kKindCellsOffset == 20307 && kKindTransitionsOffset == 20315 &&
                  kCountOffset == 20395 && kCellsOffset == 20403,
              "the offsets of docs/model_format.md");
constexpr std::size_t kCellSize = 72;
// In a cell record: the learner's 10 floats, then observed_steps, last_hits, last_misses.
constexpr std::size_t kCellLearnerOffset = 28;
constexpr std::size_t kCellObservedStepsOffset = 68;
// Version 2: the cell count right after the learners' block, 64-byte cells (8 learner floats).
constexpr std::size_t kCountOffsetV2 = 268;
constexpr std::size_t kCellsOffsetV2 = 276;
constexpr std::size_t kCellSizeV2 = 64;
constexpr std::size_t kLearnerFloatsV2 = 8;
// Version 1: no learners' block, 62-byte cells.
constexpr std::size_t kLearnersSizeV2 = kCountOffsetV2 - kLearnPriorOffset;
constexpr std::size_t kCellSizeV1 = 62;

// ---- bytes ------------------------------------------------------------------------------

// Reference CRC-32 (IEEE, reflected, init and final xor ~0: zlib's), one bit at a time.
std::uint32_t referenceCrc32(const std::string& bytes, std::size_t size) {
  std::uint32_t crc = 0xFFFFFFFFU;
  for (std::size_t i = 0; i < size; ++i) {
    crc ^= static_cast<unsigned char>(bytes[i]);
    for (int bit = 0; bit < 8; ++bit) crc = (crc >> 1) ^ (0xEDB88320U & (0U - (crc & 1U)));
  }
  return ~crc;
}

template <class T>
void putLE(std::string& bytes, std::size_t offset, T value) {
  std::uint64_t bits = 0;
  std::memcpy(&bits, &value, sizeof(T));
  for (std::size_t k = 0; k < sizeof(T); ++k) bytes[offset + k] = static_cast<char>((bits >> (8 * k)) & 0xFFU);
}

template <class T>
T getLE(const std::string& bytes, std::size_t offset) {
  std::uint64_t bits = 0;
  for (std::size_t k = 0; k < sizeof(T); ++k) {
    bits |= std::uint64_t{static_cast<unsigned char>(bytes[offset + k])} << (8 * k);
  }
  T value;
  std::memcpy(&value, &bits, sizeof(T));
  return value;
}

// Rewrites the checksum so that only the edited field is what is wrong.
void fixChecksum(std::string& bytes) {
  putLE<std::uint32_t>(bytes, bytes.size() - 4, referenceCrc32(bytes, bytes.size() - 4));
}

std::string errorOf(const std::string& bytes) {
  try {
    dog::deserializeModel(bytes);
  } catch (const std::runtime_error& error) {
    return error.what();
  } catch (const std::exception& error) {
    return std::string("WRONG EXCEPTION TYPE: ") + error.what();
  }
  return "NO EXCEPTION";
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

template <class T>
bool sameBits(T a, T b) {
  return std::memcmp(&a, &b, sizeof(T)) == 0;
}

// ---- scans: a square room with a pillar that moves ---------------------------------------

// The range along (c, s) from (x, y) to the walls of [-half, half]^2 or to a pillar of
// radius r at (px, py), whichever is nearer.
double rayRange(double x, double y, double c, double s, double half, double px, double py, double r) {
  double range = kInf;
  if (c > 1e-12) range = std::min(range, (half - x) / c);
  if (c < -1e-12) range = std::min(range, (-half - x) / c);
  if (s > 1e-12) range = std::min(range, (half - y) / s);
  if (s < -1e-12) range = std::min(range, (-half - y) / s);
  // |o + t d - p|^2 = r^2
  const double ox = x - px;
  const double oy = y - py;
  const double b = ox * c + oy * s;
  const double disc = b * b - (ox * ox + oy * oy - r * r);
  if (disc >= 0.0) {
    const double t = -b - std::sqrt(disc);
    if (t > 0.0) range = std::min(range, t);
  }
  return range;
}

// Scan `k` of a deterministic run: the laser wanders near the centre, the pillar circles.
// Some beams have no return (+inf), some are NaN.
dog::Scan roomScan(double stamp_s, int k, double centre_x = 0.0, double centre_y = 0.0) {
  dog::Scan scan;
  scan.stamp_s = stamp_s;
  scan.laser_pose.x_m = centre_x + 0.3 * std::sin(0.37 * k);
  scan.laser_pose.y_m = centre_y + 0.2 * std::cos(0.23 * k);
  scan.laser_pose.yaw_rad = 0.05 * k;
  const int beams = 120;
  scan.angle_min_rad = -kPi;
  scan.angle_increment_rad = 2.0 * kPi / beams;
  scan.range_min_m = 0.05;
  scan.range_max_m = 6.0;
  const double pillar_x = centre_x + 1.2 * std::cos(0.5 * k);
  const double pillar_y = centre_y + 1.2 * std::sin(0.5 * k);
  for (int i = 0; i < beams; ++i) {
    const double angle = scan.laser_pose.yaw_rad + scan.angle_min_rad + i * scan.angle_increment_rad;
    double range = rayRange(scan.laser_pose.x_m - centre_x, scan.laser_pose.y_m - centre_y, std::cos(angle),
                            std::sin(angle), 2.4, pillar_x - centre_x, pillar_y - centre_y, 0.25);
    if ((i + k) % 17 == 0) range = kInf;
    if ((i + 3 * k) % 29 == 0) range = std::numeric_limits<double>::quiet_NaN();
    scan.ranges_m.push_back(static_cast<float>(range));
  }
  return scan;
}

// Steps first_step .. first_step + steps - 1 of the run, every third step left out (gaps),
// three scans per step at stamps origin + (step + 0.1 / 0.5 / 0.9) * time_step.
void runSteps(dog::Mapper& mapper, int first_step, int steps, double origin_s, double centre_x = 0.0,
              double centre_y = 0.0) {
  const double dt = mapper.config().time_step_s;
  for (int step = first_step; step < first_step + steps; ++step) {
    if (step % 3 == 2) continue;
    for (const double part : {0.1, 0.5, 0.9}) {
      const int k = step * 3 + static_cast<int>(part * 10);
      const dog::ScanResult result = mapper.integrate(roomScan(origin_s + (step + part) * dt, k, centre_x, centre_y));
      ASSERT_EQ(result.status, dog::ScanStatus::kIntegrated) << result.error;
    }
  }
}

dog::MapperConfig growingLearningConfig() {
  dog::MapperConfig config;
  config.resolution_m = 0.1;
  config.time_step_s = 0.5;
  config.p_hit_given_occ = 0.75;
  config.p_hit_given_free = 0.15;
  config.prior_transitions = dog::TransitionParams{0.02, 0.03};
  config.learn_transitions = true;
  config.online_em.prior_weight = 4.0;
  config.online_em.learning_rate_floor = 0.01;
  config.online_em.p_min = 0.001;
  config.online_em.p_max = 0.45;
  config.online_em.symmetric = false;
  config.online_em.min_observed_steps = 3;
  config.learn_sensor_model = true;
  config.sensor_model_prior_weight = 20.0;
  config.sensor_model_p_min = 0.02;
  config.initial_p_occ = 0.45;
  config.static_clamp = dog::LogOddsClamp{-2.5, 3.25};
  config.max_free_range_m = 3.5;
  config.origin_x_m = -0.35;
  config.origin_y_m = 0.2;
  config.max_map_size_m = 40.0;
  return config;
}

dog::MapperConfig fixedStaticConfig() {
  dog::MapperConfig config;
  config.resolution_m = 0.125;
  config.time_step_s = 0.3;
  config.prior_transitions = dog::TransitionParams{0.0, 0.0};
  config.learn_transitions = false;
  config.online_em.symmetric = true;
  config.online_em.learning_rate_floor = 0.0;
  config.online_em.min_observed_steps = 65535;
  config.initial_p_occ = 0.3;
  config.max_free_range_m = 0.0;
  config.origin_x_m = -4.0;
  config.origin_y_m = -3.75;
  config.fixed_bounds = true;
  config.width_m = 7.0;  // the room (+-2.4) sticks out on the right: cells outside are dropped
  config.height_m = 7.5;
  config.max_map_size_m = 8.0;
  return config;
}

// A map of each cell's own online EM, as versions 1 and 2 were written.
dog::MapperConfig cellEmConfig() {
  dog::MapperConfig config = growingLearningConfig();
  config.learner = dog::TransitionLearner::kCellEm;
  return config;
}

// Kinds of cells configured with a value of its own in every field, none the default: a
// field read into another's place, or not read at all, shows.
dog::KindsConfig distinctKinds() {
  dog::KindsConfig kinds;
  kinds.initial_transitions = {{{2e-4, 3e-4}, {3e-3, 1e-3}, {0.02, 0.015}, {0.06, 0.04}, {0.2, 0.3}}};
  kinds.initial_weights = {{0.7, 0.1, 0.08, 0.07, 0.05}};
  kinds.transition_prior_weight = 20.0;
  kinds.weight_prior_cells = 50.0;
  kinds.switch_probability = 2e-3;
  kinds.forgetting = 5e-3;
  return kinds;
}

// ---- comparing mappers ------------------------------------------------------------------

std::map<XY, dog::CellState> cellsOf(const dog::Mapper& mapper) {
  std::map<XY, dog::CellState> cells;
  mapper.grid().forEachTile([&cells](const dog::CellGrid::Tile& tile) {
    for (int i = 0; i < dog::CellGrid::kTileCells; ++i) {
      if (tile.last_step[i] == dog::kNeverObserved) continue;
      dog::CellState state{tile.p_occ[i], tile.last_step[i], tile.log_odds[i], tile.p_occ_given_free[i],
                           tile.p_free_given_occ[i], {}, tile.observed_steps[i], tile.last_hits[i],
                           tile.last_misses[i]};
      for (std::size_t k = 0; k < state.em_stats.size(); ++k) state.em_stats[k] = tile.em_stats[k][i];
      cells[{tile.cellX(i), tile.cellY(i)}] = state;
    }
  });
  return cells;
}

void expectSameCells(const dog::Mapper& a, const dog::Mapper& b) {
  const auto cells_a = cellsOf(a);
  const auto cells_b = cellsOf(b);
  ASSERT_EQ(cells_a.size(), cells_b.size());
  auto it = cells_b.begin();
  for (const auto& [xy, ca] : cells_a) {
    const auto& [xy_b, cb] = *it++;
    ASSERT_EQ(xy, xy_b);
    const std::string where = "cell (" + std::to_string(xy.first) + ", " + std::to_string(xy.second) + ")";
    ASSERT_TRUE(sameBits(ca.p_occ, cb.p_occ)) << where << ": " << ca.p_occ << " vs " << cb.p_occ;
    ASSERT_EQ(ca.last_step, cb.last_step) << where;
    ASSERT_TRUE(sameBits(ca.log_odds, cb.log_odds)) << where;
    ASSERT_TRUE(sameBits(ca.p_occ_given_free, cb.p_occ_given_free)) << where;
    ASSERT_TRUE(sameBits(ca.p_free_given_occ, cb.p_free_given_occ)) << where;
    for (std::size_t k = 0; k < ca.em_stats.size(); ++k) {
      ASSERT_TRUE(sameBits(ca.em_stats[k], cb.em_stats[k])) << where << " em_stats[" << k << "]";
    }
    ASSERT_EQ(ca.observed_steps, cb.observed_steps) << where;
    ASSERT_EQ(ca.last_hits, cb.last_hits) << where;
    ASSERT_EQ(ca.last_misses, cb.last_misses) << where;
  }
  const dog::CellBox box_a = a.grid().bounds();
  const dog::CellBox box_b = b.grid().bounds();
  EXPECT_EQ(box_a.empty(), box_b.empty());
  if (!box_a.empty() && !box_b.empty()) {
    EXPECT_EQ(box_a.min_x, box_b.min_x);
    EXPECT_EQ(box_a.min_y, box_b.min_y);
    EXPECT_EQ(box_a.max_x, box_b.max_x);
    EXPECT_EQ(box_a.max_y, box_b.max_y);
  }
  EXPECT_EQ(a.grid().isFixed(), b.grid().isFixed());
}

void expectSameConfig(const dog::MapperConfig& a, const dog::MapperConfig& b) {
  EXPECT_TRUE(sameBits(a.resolution_m, b.resolution_m));
  EXPECT_TRUE(sameBits(a.time_step_s, b.time_step_s));
  EXPECT_TRUE(sameBits(a.p_hit_given_occ, b.p_hit_given_occ));
  EXPECT_TRUE(sameBits(a.p_hit_given_free, b.p_hit_given_free));
  EXPECT_TRUE(sameBits(a.prior_transitions.p_occ_given_free, b.prior_transitions.p_occ_given_free));
  EXPECT_TRUE(sameBits(a.prior_transitions.p_free_given_occ, b.prior_transitions.p_free_given_occ));
  EXPECT_EQ(a.learn_transitions, b.learn_transitions);
  EXPECT_TRUE(sameBits(a.online_em.prior_weight, b.online_em.prior_weight));
  EXPECT_TRUE(sameBits(a.online_em.learning_rate_floor, b.online_em.learning_rate_floor));
  EXPECT_TRUE(sameBits(a.online_em.p_min, b.online_em.p_min));
  EXPECT_TRUE(sameBits(a.online_em.p_max, b.online_em.p_max));
  EXPECT_EQ(a.online_em.symmetric, b.online_em.symmetric);
  EXPECT_EQ(a.online_em.min_observed_steps, b.online_em.min_observed_steps);
  EXPECT_TRUE(sameBits(a.initial_p_occ, b.initial_p_occ));
  EXPECT_TRUE(sameBits(a.static_clamp.min_log_odds, b.static_clamp.min_log_odds));
  EXPECT_TRUE(sameBits(a.static_clamp.max_log_odds, b.static_clamp.max_log_odds));
  EXPECT_TRUE(sameBits(a.max_free_range_m, b.max_free_range_m));
  EXPECT_TRUE(sameBits(a.origin_x_m, b.origin_x_m));
  EXPECT_TRUE(sameBits(a.origin_y_m, b.origin_y_m));
  EXPECT_EQ(a.fixed_bounds, b.fixed_bounds);
  EXPECT_TRUE(sameBits(a.width_m, b.width_m));
  EXPECT_TRUE(sameBits(a.height_m, b.height_m));
  EXPECT_TRUE(sameBits(a.max_map_size_m, b.max_map_size_m));
  EXPECT_EQ(a.learn_sensor_model, b.learn_sensor_model);
  EXPECT_TRUE(sameBits(a.sensor_model_prior_weight, b.sensor_model_prior_weight));
  EXPECT_TRUE(sameBits(a.sensor_model_p_min, b.sensor_model_p_min));
  EXPECT_EQ(a.learner, b.learner);
  for (int k = 0; k < dog::kKindCount; ++k) {
    const dog::TransitionParams& start_a = a.kinds.initial_transitions[k];
    const dog::TransitionParams& start_b = b.kinds.initial_transitions[k];
    EXPECT_TRUE(sameBits(start_a.p_occ_given_free, start_b.p_occ_given_free)) << "kind " << k;
    EXPECT_TRUE(sameBits(start_a.p_free_given_occ, start_b.p_free_given_occ)) << "kind " << k;
    EXPECT_TRUE(sameBits(a.kinds.initial_weights[k], b.kinds.initial_weights[k])) << "kind " << k;
  }
  EXPECT_TRUE(sameBits(a.kinds.transition_prior_weight, b.kinds.transition_prior_weight));
  EXPECT_TRUE(sameBits(a.kinds.weight_prior_cells, b.kinds.weight_prior_cells));
  EXPECT_TRUE(sameBits(a.kinds.switch_probability, b.kinds.switch_probability));
  EXPECT_TRUE(sameBits(a.kinds.forgetting, b.kinds.forgetting));
}

// The kinds' sums bit for bit (every pair of every distance bin, the memberships, the
// cells), the transitions learned from them, and the shares they give.
void expectSameKinds(const dog::Mapper& a, const dog::Mapper& b) {
  const dog::CellKinds::Sums& sums_a = a.kinds().sums();
  const dog::CellKinds::Sums& sums_b = b.kinds().sums();
  for (int k = 0; k < dog::kKindCount; ++k) {
    int differing_pairs = 0;
    for (int bin = 0; bin < dog::kGapBins; ++bin) {
      for (int pair = 0; pair < 4; ++pair) {
        if (!sameBits(sums_a.pairs[k][bin][pair], sums_b.pairs[k][bin][pair]) && differing_pairs++ < 3) {
          ADD_FAILURE() << "kind " << k << " bin " << bin << " pair " << pair << ": " << sums_a.pairs[k][bin][pair]
                        << " vs " << sums_b.pairs[k][bin][pair];
        }
      }
    }
    EXPECT_EQ(differing_pairs, 0) << "kind " << k;
    EXPECT_TRUE(sameBits(sums_a.membership[k], sums_b.membership[k])) << "kind " << k;
    EXPECT_TRUE(sameBits(a.kinds().transitions(k).p_occ_given_free, b.kinds().transitions(k).p_occ_given_free))
        << "kind " << k;
    EXPECT_TRUE(sameBits(a.kinds().transitions(k).p_free_given_occ, b.kinds().transitions(k).p_free_given_occ))
        << "kind " << k;
    EXPECT_TRUE(sameBits(a.kinds().weight(k), b.kinds().weight(k))) << "kind " << k;
  }
  EXPECT_TRUE(sameBits(sums_a.cells, sums_b.cells));
}

void expectSameTime(const dog::Mapper& a, const dog::Mapper& b) {
  ASSERT_EQ(a.clock().origin().has_value(), b.clock().origin().has_value());
  if (a.clock().origin()) {
    EXPECT_TRUE(sameBits(*a.clock().origin(), *b.clock().origin()))
        << std::hexfloat << *a.clock().origin() << " vs " << *b.clock().origin();
  }
  EXPECT_EQ(a.lastAppliedStep(), b.lastAppliedStep());
  EXPECT_TRUE(sameBits(a.clock().timeStep(), b.clock().timeStep()));
}

// Save, load, and check that the loaded mapper is the original (state and bytes).
std::unique_ptr<dog::Mapper> roundTrip(const dog::Mapper& original) {
  const std::string bytes = dog::serializeModel(original);
  std::unique_ptr<dog::Mapper> loaded = dog::deserializeModel(bytes);
  EXPECT_NE(loaded, nullptr);
  if (!loaded) return loaded;
  expectSameConfig(original.config(), loaded->config());
  expectSameTime(original, *loaded);
  expectSameCells(original, *loaded);
  expectSameKinds(original, *loaded);
  EXPECT_FALSE(loaded->gatheringStep().has_value());
  EXPECT_TRUE(dog::serializeModel(*loaded) == bytes) << "save -> load -> save is not byte-identical";
  return loaded;
}

// The real proof: both mappers go on with the same scans and stay identical.
void expectSameFuture(dog::Mapper& original, dog::Mapper& loaded, int first_step, int steps, double origin_s,
                      double centre_x = 0.0, double centre_y = 0.0) {
  runSteps(original, first_step, steps, origin_s, centre_x, centre_y);
  runSteps(loaded, first_step, steps, origin_s, centre_x, centre_y);
  original.finishStep();
  loaded.finishStep();
  expectSameTime(original, loaded);
  expectSameCells(original, loaded);
  expectSameKinds(original, loaded);
  EXPECT_TRUE(dog::serializeModel(original) == dog::serializeModel(loaded)) << "the continued maps differ";
}

// A small model (a few dozen cells) for the loops over every byte.
std::string smallModel() {
  dog::MapperConfig config = fixedStaticConfig();
  config.learn_transitions = true;
  config.prior_transitions = dog::TransitionParams{0.05, 0.05};
  config.online_em.min_observed_steps = 2;
  config.width_m = 1.0;
  config.height_m = 1.0;
  config.origin_x_m = -0.5;
  config.origin_y_m = -0.5;
  dog::Mapper mapper(config);
  for (int step = 0; step < 4; ++step) {
    dog::Scan scan;
    scan.stamp_s = 100.0 + step * config.time_step_s;
    scan.angle_min_rad = 0.0;
    scan.angle_increment_rad = kPi / 2.0;
    scan.range_min_m = 0.0;
    scan.range_max_m = 5.0;
    scan.ranges_m = {0.3f, step % 2 == 0 ? 0.4f : 0.2f, 5.0f};
    EXPECT_EQ(mapper.integrate(scan).status, dog::ScanStatus::kIntegrated);
  }
  mapper.finishStep();
  return dog::serializeModel(mapper);
}

// A temporary directory, removed with everything in it at the end of the test.
class TempDir {
 public:
  TempDir() {
    static std::atomic<int> counter{0};
    path_ = fs::temp_directory_path() /
            ("dog_model_io_" + std::to_string(::getpid()) + "_" + std::to_string(counter++));
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ignored;
    fs::remove_all(path_, ignored);
  }
  std::string file(const std::string& name) const { return (path_ / name).string(); }
  std::vector<std::string> entries() const {
    std::vector<std::string> names;
    for (const auto& entry : fs::directory_iterator(path_)) names.push_back(entry.path().filename().string());
    std::sort(names.begin(), names.end());
    return names;
  }

 private:
  fs::path path_;
};

std::string readFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void writeFile(const std::string& path, const std::string& contents) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << contents;
}

}  // namespace

// ---- round trips -------------------------------------------------------------------------

TEST(ModelIoRoundTrip, GrowingLearningMapIsTheSameMapAndGoesOnTheSame) {
  dog::Mapper original(growingLearningConfig());
  const double origin_s = 1700000000.123;
  runSteps(original, 0, 40, origin_s);
  original.finishStep();
  ASSERT_GT(cellsOf(original).size(), 1000U);
  ASSERT_EQ(original.lastAppliedStep(), std::optional<std::int64_t>(39));
  // Learning has moved transitions away from the prior somewhere.
  bool learned = false;
  for (const auto& [xy, cell] : cellsOf(original)) {
    learned = learned || cell.p_occ_given_free != static_cast<float>(original.config().prior_transitions.p_occ_given_free);
  }
  ASSERT_TRUE(learned);

  std::unique_ptr<dog::Mapper> loaded = roundTrip(original);
  ASSERT_NE(loaded, nullptr);
  // On, with a step right after the last one, gaps, and the laser moved so that the map grows.
  expectSameFuture(original, *loaded, 40, 25, origin_s, 1.5, -1.0);
  // And once more, through a second save and load.
  std::unique_ptr<dog::Mapper> reloaded = roundTrip(*loaded);
  ASSERT_NE(reloaded, nullptr);
  expectSameFuture(original, *reloaded, 70, 10, origin_s);
}

TEST(ModelIoRoundTrip, FixedBoundsStaticMapIsTheSameMapAndGoesOnTheSame) {
  dog::Mapper original(fixedStaticConfig());
  const double origin_s = 12.7;
  runSteps(original, 0, 30, origin_s);
  original.finishStep();
  ASSERT_GT(cellsOf(original).size(), 500U);
  std::unique_ptr<dog::Mapper> loaded = roundTrip(original);
  ASSERT_NE(loaded, nullptr);
  EXPECT_TRUE(loaded->grid().isFixed());
  expectSameFuture(original, *loaded, 31, 20, origin_s, 0.5, 0.5);
}

TEST(ModelIoRoundTrip, EmptyMapperRoundTripsAndStartsTheSame) {
  dog::Mapper original(growingLearningConfig());
  const std::string bytes = dog::serializeModel(original);
  EXPECT_EQ(bytes.size(), kCellsOffset + 4);
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kHasOriginOffset), 0);
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kHasLastStepOffset), 0);
  std::unique_ptr<dog::Mapper> loaded = roundTrip(original);
  ASSERT_NE(loaded, nullptr);
  EXPECT_FALSE(loaded->clock().origin().has_value());
  EXPECT_FALSE(loaded->lastAppliedStep().has_value());
  expectSameFuture(original, *loaded, 0, 10, 3.25);
}

TEST(ModelIoRoundTrip, EmptyFixedMapperRoundTrips) {
  dog::Mapper original(fixedStaticConfig());
  std::unique_ptr<dog::Mapper> loaded = roundTrip(original);
  ASSERT_NE(loaded, nullptr);
  expectSameFuture(original, *loaded, 0, 5, -7.5);
}

TEST(ModelIoRoundTrip, StepStillGatheredIsNotSaved) {
  // Saved while step 6 is gathered: the file holds steps up to 4 (5 had no scans); given
  // step 6's scans again, the loaded mapper ends where the original does.
  dog::Mapper original(growingLearningConfig());
  const double origin_s = 50.0;
  runSteps(original, 0, 6, origin_s);
  runSteps(original, 6, 1, origin_s);
  ASSERT_EQ(original.gatheringStep(), std::optional<std::int64_t>(6));
  const std::string bytes = dog::serializeModel(original);
  std::unique_ptr<dog::Mapper> loaded = dog::deserializeModel(bytes);
  expectSameTime(original, *loaded);
  expectSameCells(original, *loaded);
  EXPECT_EQ(loaded->lastAppliedStep(), std::optional<std::int64_t>(4));
  EXPECT_FALSE(loaded->gatheringStep().has_value());
  runSteps(*loaded, 6, 1, origin_s);
  original.finishStep();
  loaded->finishStep();
  expectSameCells(original, *loaded);
  EXPECT_TRUE(dog::serializeModel(original) == dog::serializeModel(*loaded));
}

TEST(ModelIoRoundTrip, ClockStartedWithoutAppliedStep) {
  dog::Mapper original(growingLearningConfig());
  ASSERT_EQ(original.integrate(roomScan(8.0, 0)).status, dog::ScanStatus::kIntegrated);
  const std::string bytes = dog::serializeModel(original);
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kHasOriginOffset), 1);
  EXPECT_EQ(getLE<double>(bytes, kOriginOffset), 8.0);
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kHasLastStepOffset), 0);
  EXPECT_EQ(getLE<std::uint64_t>(bytes, kCountOffset), 0U);
  std::unique_ptr<dog::Mapper> loaded = dog::deserializeModel(bytes);
  expectSameTime(original, *loaded);
  EXPECT_TRUE(dog::serializeModel(*loaded) == bytes);
}

TEST(ModelIoRoundTrip, ClockOriginComesBackExactly) {
  // Awkward stamps and steps: the origin must come back bit for bit (same steps for the
  // same stamps), also after restartClockAt, which moves the origin by a step multiple.
  for (const double time_step_s : {1.0, 0.1, 0.05, 0.3, 7.3}) {
    for (const double stamp_s : {0.0, 0.001, 0.123456789, 3.0, -3.3, 1234.5678, 1.7e9 + 0.123456, 1e12 + 0.5}) {
      SCOPED_TRACE("time_step " + std::to_string(time_step_s) + " stamp " + std::to_string(stamp_s));
      dog::MapperConfig config = growingLearningConfig();
      config.time_step_s = time_step_s;
      dog::Mapper original(config);
      ASSERT_EQ(original.integrate(roomScan(stamp_s, 1)).status, dog::ScanStatus::kIntegrated);
      original.finishStep();
      std::unique_ptr<dog::Mapper> loaded = roundTrip(original);
      ASSERT_NE(loaded, nullptr);
      original.restartClockAt(stamp_s * 0.5 + 0.77);
      const std::unique_ptr<dog::Mapper> restarted = roundTrip(original);
      ASSERT_NE(restarted, nullptr);
      // A stamp just after a step boundary lands in the same step on both.
      const double boundary = original.clock().stepStart(3);
      EXPECT_EQ(original.clock().stepOf(boundary), restarted->clock().stepOf(boundary));
      EXPECT_EQ(original.clock().stepOf(std::nextafter(boundary, -kInf)),
                restarted->clock().stepOf(std::nextafter(boundary, -kInf)));
    }
  }
}

TEST(ModelIoRoundTrip, LargeMapWithNegativeCoordinatesAcrossManyTiles) {
  // 300 x 300 cells around the origin (tiles with negative coordinates, partly filled), every
  // field with distinct values: the order of the records and all fields survive. Online EM's
  // statistics may be any non-negative numbers (a kinds cell's must sum to 1).
  dog::MapperConfig config = growingLearningConfig();
  config.learner = dog::TransitionLearner::kCellEm;
  dog::Mapper original(config);
  original.restoreTime(0.0, 1000);
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  for (std::int32_t y = -150; y < 150; ++y) {
    for (std::int32_t x = -150; x < 150; ++x) {
      if ((x * 7 + y * 13) % 11 == 0) continue;  // holes
      dog::CellState state{};
      state.p_occ = unit(rng);
      state.last_step = static_cast<std::int32_t>(rng() % 1001);
      state.log_odds = unit(rng) * 4.0f - 2.0f;
      state.p_occ_given_free = unit(rng) * 0.5f;
      state.p_free_given_occ = unit(rng) * 0.5f;
      for (float& s : state.em_stats) s = unit(rng) * 100.0f;
      state.observed_steps = static_cast<std::uint16_t>(rng());
      original.restoreCell(x, y, state);
    }
  }
  const std::string bytes = dog::serializeModel(original);
  const std::size_t count = cellsOf(original).size();
  ASSERT_EQ(bytes.size(), kCellsOffset + count * kCellSize + 4);
  // Records by row (y ascending), then x ascending (docs/model_format.md).
  XY previous{std::numeric_limits<std::int32_t>::min(), std::numeric_limits<std::int32_t>::min()};
  for (std::size_t i = 0; i < count; ++i) {
    const XY xy{getLE<std::int32_t>(bytes, kCellsOffset + i * kCellSize),
                getLE<std::int32_t>(bytes, kCellsOffset + i * kCellSize + 4)};
    ASSERT_LT(std::make_pair(previous.second, previous.first), std::make_pair(xy.second, xy.first)) << i;
    previous = xy;
  }
  std::unique_ptr<dog::Mapper> loaded = roundTrip(original);
  ASSERT_NE(loaded, nullptr);
  expectSameFuture(original, *loaded, 1001, 5, 0.0);
}

// ---- the bytes are the documented ones -----------------------------------------------------

TEST(ModelIoFormat, BytesAreAsDocumented) {
  dog::MapperConfig config = growingLearningConfig();
  config.kinds = distinctKinds();
  dog::Mapper mapper(config);
  runSteps(mapper, 0, 6, 20.0);
  mapper.finishStep();
  // Sums that are not zero, found at their offsets (in the first bin; each pair goes to its
  // cell's likeliest kind, here the stable one); KindsBlockHoldsEveryValueAtItsOffset checks
  // every slot with values of its own.
  const dog::CellKinds::Sums& sums = mapper.kinds().sums();
  ASSERT_GT(sums.cells, 0.0);
  ASSERT_GT(sums.pairs[0][0][3], 0.0);  // kind 0, free then and now, one step apart
  const std::string bytes = dog::serializeModel(mapper);
  const auto cells = cellsOf(mapper);
  ASSERT_EQ(bytes.size(), kCellsOffset + cells.size() * kCellSize + 4);
  ASSERT_EQ(bytes.size(), 20407 + 72 * cells.size());
  EXPECT_EQ(bytes.substr(0, 8), "DOGMODEL");
  EXPECT_EQ(getLE<std::uint32_t>(bytes, kVersionOffset), 3U);
  EXPECT_EQ(dog::kModelFormatVersion, 3U);
  EXPECT_EQ(getLE<double>(bytes, kResolutionOffset), config.resolution_m);
  EXPECT_EQ(getLE<double>(bytes, kPHitGivenOccOffset), config.p_hit_given_occ);
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kLearnOffset), 1);
  EXPECT_EQ(getLE<double>(bytes, kLearnOffset + 1), config.online_em.prior_weight);
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kSymmetricOffset), 0);
  EXPECT_EQ(getLE<std::uint32_t>(bytes, kMinObservedOffset), config.online_em.min_observed_steps);
  EXPECT_EQ(getLE<double>(bytes, kInitialPOccOffset), config.initial_p_occ);
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kFixedOffset), 0);
  EXPECT_EQ(getLE<double>(bytes, kMaxMapSizeOffset), config.max_map_size_m);
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kHasOriginOffset), 1);
  EXPECT_EQ(getLE<double>(bytes, kOriginOffset), 20.0 + 0.1 * config.time_step_s);  // the first stamp
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kHasLastStepOffset), 1);
  EXPECT_EQ(getLE<std::int64_t>(bytes, kLastStepOffset), 4);  // step 5 had no scans
  EXPECT_EQ(getLE<std::uint64_t>(bytes, kCountOffset), cells.size());
  // Version 2's learners' block.
  // The removed empirical-Bayes prior's fields hold its defaults.
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kLearnPriorOffset), 0);
  EXPECT_EQ(getLE<double>(bytes, kLearnPriorOffset + 1), 10.0);
  // The removed step-size schedule's fields hold what the harmonic schedule wrote.
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kScheduleOffset), 0);  // harmonic
  EXPECT_EQ(getLE<double>(bytes, kScheduleOffset + 1), 0.6);
  EXPECT_EQ(getLE<double>(bytes, kScheduleOffset + 9), 2.0);
  EXPECT_EQ(getLE<std::uint32_t>(bytes, kScheduleOffset + 17), 0U);
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kLearnSensorOffset), 1);
  EXPECT_EQ(getLE<double>(bytes, kLearnSensorOffset + 1), config.sensor_model_prior_weight);
  EXPECT_EQ(getLE<double>(bytes, kLearnSensorOffset + 9), config.sensor_model_p_min);
  const dog::SensorModelStats& stats = mapper.sensorModelStats();
  EXPECT_EQ(getLE<double>(bytes, kSensorStatsOffset), stats.trials[0]);
  EXPECT_EQ(getLE<double>(bytes, kSensorStatsOffset + 8), stats.trials[1]);
  EXPECT_EQ(getLE<double>(bytes, kSensorStatsOffset + 16), stats.hits[0]);
  EXPECT_EQ(getLE<double>(bytes, kSensorStatsOffset + 24), stats.hits[1]);
  // Version 3's block: the learner, the kinds' configuration, their sums.
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kLearnerOffset), 1);  // kinds
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kKindCountOffset), 5);
  for (int k = 0; k < dog::kKindCount; ++k) {
    const std::size_t kind = static_cast<std::size_t>(k);
    EXPECT_EQ(getLE<double>(bytes, kKindInitialTransitionsOffset + 16 * kind),
              config.kinds.initial_transitions[kind].p_occ_given_free);
    EXPECT_EQ(getLE<double>(bytes, kKindInitialTransitionsOffset + 16 * kind + 8),
              config.kinds.initial_transitions[kind].p_free_given_occ);
    EXPECT_EQ(getLE<double>(bytes, kKindInitialWeightsOffset + 8 * kind), config.kinds.initial_weights[kind]);
    for (std::size_t bin = 0; bin < kKindBins; ++bin) {
      for (std::size_t pair = 0; pair < 4; ++pair) {
        ASSERT_TRUE(sameBits(getLE<double>(bytes, kKindPairsOffset + 8 * ((kind * kKindBins + bin) * 4 + pair)),
                             sums.pairs[kind][bin][pair]))
            << "kind " << k << " bin " << bin << " pair " << pair;
      }
    }
    EXPECT_EQ(getLE<double>(bytes, kKindMembershipOffset + 8 * kind), sums.membership[kind]);
    EXPECT_EQ(getLE<double>(bytes, kKindTransitionsOffset + 16 * kind), mapper.kinds().transitions(k).p_occ_given_free);
    EXPECT_EQ(getLE<double>(bytes, kKindTransitionsOffset + 16 * kind + 8),
              mapper.kinds().transitions(k).p_free_given_occ);
  }
  EXPECT_EQ(getLE<double>(bytes, kKindTransitionPriorWeightOffset), config.kinds.transition_prior_weight);
  EXPECT_EQ(getLE<double>(bytes, kKindWeightPriorCellsOffset), config.kinds.weight_prior_cells);
  EXPECT_EQ(getLE<double>(bytes, kKindSwitchProbabilityOffset), config.kinds.switch_probability);
  EXPECT_EQ(getLE<double>(bytes, kKindForgettingOffset), config.kinds.forgetting);
  // The removed kinds' choices hold the ones left.
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kKindSummaryOffset), 0);   // geometric mean
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kKindCountingOffset), 1);  // most probable
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kKindLearnFromGapsOffset), 1);
  EXPECT_EQ(getLE<std::uint16_t>(bytes, kKindBinCountOffset), kKindBins);
  EXPECT_EQ(static_cast<std::size_t>(dog::kGapBins), kKindBins);
  EXPECT_EQ(getLE<double>(bytes, kKindCellsOffset), sums.cells);
  // The first record is the cell with the smallest (y, x).
  XY first = cells.begin()->first;
  for (const auto& kv : cells) {
    if (std::make_pair(kv.first.second, kv.first.first) < std::make_pair(first.second, first.first)) first = kv.first;
  }
  const dog::CellState& c = cells.at(first);
  const std::size_t r = kCellsOffset;
  EXPECT_EQ(getLE<std::int32_t>(bytes, r + 0), first.first);
  EXPECT_EQ(getLE<std::int32_t>(bytes, r + 4), first.second);
  EXPECT_TRUE(sameBits(getLE<float>(bytes, r + 8), c.p_occ));
  EXPECT_EQ(getLE<std::int32_t>(bytes, r + 12), c.last_step);
  EXPECT_TRUE(sameBits(getLE<float>(bytes, r + 16), c.log_odds));
  EXPECT_TRUE(sameBits(getLE<float>(bytes, r + 20), c.p_occ_given_free));
  EXPECT_TRUE(sameBits(getLE<float>(bytes, r + 24), c.p_free_given_occ));
  // The kind posteriors p(kind, state) at 2 * kind + state: a distribution.
  ASSERT_EQ(c.em_stats.size(), 10U);
  double total = 0.0;
  for (std::size_t k = 0; k < 10; ++k) {
    EXPECT_TRUE(sameBits(getLE<float>(bytes, r + 28 + 4 * k), c.em_stats[k])) << k;
    total += c.em_stats[k];
  }
  EXPECT_NEAR(total, 1.0, 1e-5);
  EXPECT_EQ(getLE<std::uint16_t>(bytes, r + 68), c.observed_steps);
  EXPECT_EQ(getLE<std::uint8_t>(bytes, r + 70), c.last_hits);
  EXPECT_EQ(getLE<std::uint8_t>(bytes, r + 71), c.last_misses);
  // The checksum is zlib's CRC-32 of everything before it.
  EXPECT_EQ(referenceCrc32("123456789", 9), 0xCBF43926U);  // the reference's check value
  EXPECT_EQ(getLE<std::uint32_t>(bytes, bytes.size() - 4), referenceCrc32(bytes, bytes.size() - 4));
}

TEST(ModelIoFormat, KindsBlockHoldsEveryValueAtItsOffset) {
  // Sums and learned transitions restored with a value of their own in every place: each
  // is found at its documented offset ([kind][bin][2 i + j]), and comes back from the file.
  dog::MapperConfig config = growingLearningConfig();
  config.kinds = distinctKinds();
  dog::Mapper mapper(config);
  runSteps(mapper, 0, 3, 20.0);
  mapper.finishStep();
  dog::CellKinds::Sums sums;
  for (std::size_t k = 0; k < 5; ++k) {
    for (std::size_t bin = 0; bin < kKindBins; ++bin) {
      for (std::size_t pair = 0; pair < 4; ++pair) sums.pairs[k][bin][pair] = 0.5 + ((k * kKindBins + bin) * 4 + pair);
    }
    sums.membership[k] = 1e5 + 0.25 * k;
  }
  sums.cells = 2e5 + 0.75;
  std::array<dog::TransitionParams, dog::kKindCount> learned{};
  for (std::size_t k = 0; k < 5; ++k) learned[k] = dog::TransitionParams{0.0011 + 0.01 * k, 0.0013 + 0.02 * k};
  learned[4].p_free_given_occ = config.online_em.p_max;  // the bounds are allowed
  learned[1].p_occ_given_free = config.online_em.p_min;
  // The stable kind is not learned: it keeps the configured transitions (cell_kinds.h).
  learned[dog::kStableKind] = mapper.kinds().transitions(dog::kStableKind);
  mapper.restoreKinds(sums, learned);
  const std::string bytes = dog::serializeModel(mapper);
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kKindCountingOffset), 1);
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kKindLearnFromGapsOffset), 1);
  EXPECT_EQ(getLE<std::uint16_t>(bytes, kKindBinCountOffset), kKindBins);
  std::size_t offset = kKindPairsOffset;
  for (std::size_t k = 0; k < 5; ++k) {
    for (std::size_t bin = 0; bin < kKindBins; ++bin) {
      for (std::size_t pair = 0; pair < 4; ++pair, offset += 8) {
        ASSERT_EQ(getLE<double>(bytes, offset), 0.5 + ((k * kKindBins + bin) * 4 + pair))
            << "kind " << k << " bin " << bin << " pair " << pair;
      }
    }
  }
  ASSERT_EQ(offset, kKindMembershipOffset);
  for (std::size_t k = 0; k < 5; ++k) {
    EXPECT_EQ(getLE<double>(bytes, kKindMembershipOffset + 8 * k), 1e5 + 0.25 * k) << k;
    EXPECT_EQ(getLE<double>(bytes, kKindTransitionsOffset + 16 * k), learned[k].p_occ_given_free) << k;
    EXPECT_EQ(getLE<double>(bytes, kKindTransitionsOffset + 16 * k + 8), learned[k].p_free_given_occ) << k;
  }
  EXPECT_EQ(getLE<double>(bytes, kKindCellsOffset), 2e5 + 0.75);
  EXPECT_EQ(getLE<std::uint64_t>(bytes, kCountOffset), cellsOf(mapper).size());
  const std::unique_ptr<dog::Mapper> loaded = roundTrip(mapper);
  ASSERT_NE(loaded, nullptr);
  for (std::size_t k = 0; k < 5; ++k) {
    const dog::TransitionParams& back = loaded->kinds().transitions(static_cast<int>(k));
    EXPECT_TRUE(sameBits(back.p_occ_given_free, learned[k].p_occ_given_free)) << k;
    EXPECT_TRUE(sameBits(back.p_free_given_occ, learned[k].p_free_given_occ)) << k;
  }
}

TEST(ModelIoFormat, LearnerChoicesAreTheDocumentedNumbers) {
  using Learner = dog::TransitionLearner;
  for (const auto& [learner, learner_byte] : {std::pair{Learner::kCellEm, 0}, std::pair{Learner::kKinds, 1}}) {
    dog::MapperConfig config = fixedStaticConfig();
    config.learner = learner;
    const dog::Mapper mapper(config);
    const std::string bytes = dog::serializeModel(mapper);
    EXPECT_EQ(getLE<std::uint8_t>(bytes, kLearnerOffset), learner_byte);
    const std::unique_ptr<dog::Mapper> loaded = roundTrip(mapper);
    ASSERT_NE(loaded, nullptr);
    EXPECT_EQ(loaded->config().learner, learner);
  }
}

// Files written with the kinds' other summaries, counting or with pairs of consecutive steps
// only (choices removed after a9ed7d5) still load: their kinds go on with the choices left.
TEST(ModelIoFormat, FilesWithTheRemovedKindsChoicesLoad) {
  dog::MapperConfig config = fixedStaticConfig();
  config.learner = dog::TransitionLearner::kKinds;
  const std::string bytes = dog::serializeModel(dog::Mapper(config));
  for (int summary = 0; summary <= 2; ++summary) {
    for (int counting = 0; counting <= 1; ++counting) {
      for (int learn_from_gaps = 0; learn_from_gaps <= 1; ++learn_from_gaps) {
        std::string edited = bytes;
        edited[kKindSummaryOffset] = static_cast<char>(summary);
        edited[kKindCountingOffset] = static_cast<char>(counting);
        edited[kKindLearnFromGapsOffset] = static_cast<char>(learn_from_gaps);
        fixChecksum(edited);
        const std::unique_ptr<dog::Mapper> loaded = dog::deserializeModel(edited);
        ASSERT_NE(loaded, nullptr);
        EXPECT_EQ(dog::serializeModel(*loaded), bytes) << summary << counting << learn_from_gaps;
      }
    }
  }
}

namespace {

// A version 3 model as version 2 wrote it: without the learner and kinds block, and 8
// learner floats per cell (only a model of learner cell_em is one version 2 could write).
std::string asVersion2(const std::string& v3) {
  std::string v2 = v3.substr(0, kLearnerOffset) + v3.substr(kCountOffset, 8);
  putLE<std::uint32_t>(v2, kVersionOffset, 2);
  const std::uint64_t count = getLE<std::uint64_t>(v3, kCountOffset);
  for (std::uint64_t i = 0; i < count; ++i) {
    const std::string cell = v3.substr(kCellsOffset + i * kCellSize, kCellSize);
    v2 += cell.substr(0, kCellLearnerOffset + 4 * kLearnerFloatsV2) + cell.substr(kCellObservedStepsOffset);
  }
  v2 += std::string(4, '\0');
  fixChecksum(v2);
  return v2;
}

// A version 2 model as version 1 wrote it: without the learners' block and the cells' last
// evidence.
std::string asVersion1(const std::string& v2) {
  std::string v1 = v2.substr(0, kLearnPriorOffset) + v2.substr(kCountOffsetV2, 8);
  putLE<std::uint32_t>(v1, kVersionOffset, 1);
  const std::uint64_t count = getLE<std::uint64_t>(v2, kCountOffsetV2);
  for (std::uint64_t i = 0; i < count; ++i) v1 += v2.substr(kCellsOffsetV2 + i * kCellSizeV2, kCellSizeV1);
  v1 += std::string(4, '\0');
  fixChecksum(v1);
  return v1;
}

}  // namespace

TEST(ModelIoFormat, Version2FilesAreReadAsEachCellsOnlineEm) {
  dog::Mapper original(cellEmConfig());
  const double origin_s = 20.0;
  runSteps(original, 0, 12, origin_s);
  original.finishStep();
  const std::string v3 = dog::serializeModel(original);
  const std::uint64_t count = getLE<std::uint64_t>(v3, kCountOffset);
  const std::string v2 = asVersion2(v3);
  ASSERT_EQ(v2.size(), kCellsOffsetV2 + count * kCellSizeV2 + 4);
  std::unique_ptr<dog::Mapper> loaded = dog::deserializeModel(v2);
  ASSERT_NE(loaded, nullptr);
  EXPECT_EQ(loaded->config().learner, dog::TransitionLearner::kCellEm);
  // Everything else version 2 has comes back; the kinds take KindsConfig's defaults and no sums.
  expectSameConfig(original.config(), loaded->config());
  expectSameTime(original, *loaded);
  EXPECT_EQ(loaded->kinds().sums().cells, 0.0);
  for (int state = 0; state < 2; ++state) {
    EXPECT_EQ(loaded->sensorModelStats().trials[state], original.sensorModelStats().trials[state]);
    EXPECT_EQ(loaded->sensorModelStats().hits[state], original.sensorModelStats().hits[state]);
  }
  // Each cell's 8 EM statistics come back, the learner's two further floats are 0.
  const auto original_cells = cellsOf(original);
  const auto loaded_cells = cellsOf(*loaded);
  ASSERT_EQ(original_cells.size(), loaded_cells.size());
  bool learned = false;
  for (const auto& [xy, cell] : original_cells) {
    const dog::CellState& back = loaded_cells.at(xy);
    for (std::size_t k = 0; k < kLearnerFloatsV2; ++k) {
      ASSERT_TRUE(sameBits(back.em_stats[k], cell.em_stats[k])) << k;
      learned = learned || cell.em_stats[k] != 0.0f;
    }
    ASSERT_EQ(back.em_stats[8], 0.0f);
    ASSERT_EQ(back.em_stats[9], 0.0f);
    ASSERT_TRUE(sameBits(back.p_occ, cell.p_occ));
    ASSERT_EQ(back.observed_steps, cell.observed_steps);
    ASSERT_EQ(back.last_hits, cell.last_hits);
    ASSERT_EQ(back.last_misses, cell.last_misses);
  }
  EXPECT_TRUE(learned);
  // Each cell's online EM keeps none of its state in the two further floats: the map read
  // from version 2 is the map, saved again it is the version 3 file, and it maps on the same.
  expectSameCells(original, *loaded);
  EXPECT_TRUE(dog::serializeModel(*loaded) == v3);
  expectSameFuture(original, *loaded, 12, 10, origin_s);
  // Damaged version 2 files are refused like version 3 ones.
  EXPECT_TRUE(contains(errorOf(v2.substr(0, v2.size() - 1)), "truncated")) << errorOf(v2.substr(0, v2.size() - 1));
  std::string flipped = v2;
  flipped[kCellsOffsetV2 + 9] ^= 0x10;
  EXPECT_TRUE(contains(errorOf(flipped), "checksum")) << errorOf(flipped);
}

TEST(ModelIoFormat, Version1FilesAreReadWithTheDefaultsOfWhatTheyLack) {
  const dog::MapperConfig config = cellEmConfig();
  dog::Mapper mapper(config);
  runSteps(mapper, 0, 6, 20.0);
  mapper.finishStep();
  const std::string v3 = dog::serializeModel(mapper);
  const std::uint64_t count = getLE<std::uint64_t>(v3, kCountOffset);
  const std::string v2 = asVersion2(v3);
  const std::string v1 = asVersion1(v2);
  ASSERT_EQ(v1.size(), v2.size() - kLearnersSizeV2 - (kCellSizeV2 - kCellSizeV1) * count);
  const std::unique_ptr<dog::Mapper> loaded = dog::deserializeModel(v1);
  ASSERT_NE(loaded, nullptr);
  // What version 1 has comes back; what it lacks takes MapperConfig's defaults, but the
  // learner: its cells hold each cell's online EM statistics.
  const dog::MapperConfig defaults;
  EXPECT_EQ(loaded->config().p_hit_given_occ, config.p_hit_given_occ);
  EXPECT_EQ(loaded->config().online_em.prior_weight, config.online_em.prior_weight);
  EXPECT_EQ(loaded->config().learn_sensor_model, defaults.learn_sensor_model);
  EXPECT_NE(defaults.learner, dog::TransitionLearner::kCellEm);
  EXPECT_EQ(loaded->config().learner, dog::TransitionLearner::kCellEm);
  EXPECT_EQ(loaded->kinds().sums().cells, 0.0);
  EXPECT_EQ(loaded->sensorModelStats().trials[0], 0.0);
  EXPECT_EQ(loaded->sensor().pHitGivenOcc(), config.p_hit_given_occ);
  const auto original_cells = cellsOf(mapper);
  const auto loaded_cells = cellsOf(*loaded);
  ASSERT_EQ(original_cells.size(), loaded_cells.size());
  for (const auto& [xy, cell] : original_cells) {
    const dog::CellState& back = loaded_cells.at(xy);
    EXPECT_TRUE(sameBits(back.p_occ, cell.p_occ));
    EXPECT_EQ(back.last_step, cell.last_step);
    EXPECT_EQ(back.observed_steps, cell.observed_steps);
    for (std::size_t k = 0; k < kLearnerFloatsV2; ++k) EXPECT_TRUE(sameBits(back.em_stats[k], cell.em_stats[k])) << k;
    EXPECT_EQ(back.em_stats[8], 0.0f);
    EXPECT_EQ(back.em_stats[9], 0.0f);
    EXPECT_EQ(back.last_hits, 0);
    EXPECT_EQ(back.last_misses, 0);
  }
  // Saved again, it is a version 3 file of learner cell_em.
  const std::string saved = dog::serializeModel(*loaded);
  EXPECT_EQ(getLE<std::uint32_t>(saved, kVersionOffset), 3U);
  EXPECT_EQ(getLE<std::uint8_t>(saved, kLearnerOffset), 0);
  // Damaged version 1 files are refused like version 3 ones.
  EXPECT_TRUE(contains(errorOf(v1.substr(0, v1.size() - 1)), "truncated")) << errorOf(v1.substr(0, v1.size() - 1));
}

TEST(ModelIoRoundTrip, LearnedSensorModelComesBack) {
  dog::Mapper original(growingLearningConfig());
  runSteps(original, 0, 30, 50.0);
  original.finishStep();
  ASSERT_GT(original.sensorModelStats().trials[0], 0.0);
  ASSERT_NE(original.sensor().pHitGivenOcc(), original.config().p_hit_given_occ);  // it learned
  const std::unique_ptr<dog::Mapper> loaded = roundTrip(original);
  ASSERT_NE(loaded, nullptr);
  EXPECT_EQ(loaded->sensor().pHitGivenOcc(), original.sensor().pHitGivenOcc());
  EXPECT_EQ(loaded->sensor().pHitGivenFree(), original.sensor().pHitGivenFree());
  for (int state = 0; state < 2; ++state) {
    EXPECT_EQ(loaded->sensorModelStats().trials[state], original.sensorModelStats().trials[state]);
    EXPECT_EQ(loaded->sensorModelStats().hits[state], original.sensorModelStats().hits[state]);
  }
}

TEST(ModelIoRoundTrip, LearnedKindsComeBackAndGoOnTheSame) {
  // The pair sums of every distance bin, the memberships, the cells and the transitions the
  // kinds learned come back bit for bit (expectSameKinds), and the loaded mapper maps on to
  // the same bytes as the original (expectSameFuture).
  {
    dog::MapperConfig config = growingLearningConfig();
    config.kinds = distinctKinds();
    ASSERT_EQ(config.learner, dog::TransitionLearner::kKinds);  // the default
    dog::Mapper original(config);
    const double origin_s = 4321.125;
    runSteps(original, 0, 300, origin_s);
    original.finishStep();
    // The kinds learned something: changes in the pairs of several kinds, pairs in the bins the
    // setting allows (steps % 3 == 2 have no scans: gaps of 2 steps, bin 1), transitions
    // away from where they began.
    const dog::CellKinds::Sums& sums = original.kinds().sums();
    ASSERT_GT(sums.cells, 1000.0);
    bool moved = false;
    int bins_used = 0;
    for (int bin = 0; bin < dog::kGapBins; ++bin) {
      double total = 0.0;
      for (int k = 0; k < dog::kKindCount; ++k) {
        for (const double value : sums.pairs[k][bin]) total += value;
      }
      bins_used += total > 0.0 ? 1 : 0;
    }
    ASSERT_GE(bins_used, 2);
    int kinds_with_changes = 0;
    for (int k = 0; k < dog::kKindCount; ++k) {
      ASSERT_GT(sums.membership[k], 0.0) << k;
      double changes = 0.0;
      for (const auto& bin : sums.pairs[k]) changes += bin[1] + bin[2];  // occ -> free, free -> occ
      kinds_with_changes += changes > 0.0 ? 1 : 0;
      const dog::TransitionParams& start = config.kinds.initial_transitions[k];
      moved = moved || original.kinds().transitions(k).p_occ_given_free != start.p_occ_given_free ||
              original.kinds().transitions(k).p_free_given_occ != start.p_free_given_occ;
    }
    ASSERT_GE(kinds_with_changes, 2);
    ASSERT_TRUE(moved);

    std::unique_ptr<dog::Mapper> loaded = roundTrip(original);  // also the kinds and every cell's 10 floats
    ASSERT_NE(loaded, nullptr);
    expectSameFuture(original, *loaded, 300, 40, origin_s, 0.4, -0.3);
  }
}

// A kind whose fit ends at a bound of its transitions must save a file that loads: exp(log x)
// is not always x (2e-4: one ulp below), so CellKinds::fitPairs clamps its result to
// [p_min, p_max]; without that, with online_em.p_min 2e-4 the floor's kind was saved below
// p_min and CellKinds::restore refused the file.
TEST(ModelIoRoundTrip, KindsFittedAtTheirBoundsLoad) {
  for (const double p_min : {1e-4, 2e-4, 3e-4, 7e-4, 0.0011}) {
    SCOPED_TRACE("p_min " + std::to_string(p_min));
    dog::MapperConfig config = growingLearningConfig();
    config.online_em.p_min = p_min;
    dog::Mapper original(config);
    runSteps(original, 0, 30, 10.0);
    original.finishStep();
    for (int k = 0; k < dog::kKindCount; ++k) {
      EXPECT_GE(original.kinds().transitions(k).p_occ_given_free, p_min) << "kind " << k;
      EXPECT_GE(original.kinds().transitions(k).p_free_given_occ, p_min) << "kind " << k;
    }
    EXPECT_EQ(errorOf(dog::serializeModel(original)), "NO EXCEPTION");
  }
}

TEST(ModelIoRoundTrip, CellEmLearnerMapIsTheSameMapAndGoesOnTheSame) {
  // Each cell's own online EM: its statistics in the first 8 floats; the kinds' configuration
  // is kept though unused.
  dog::MapperConfig config = cellEmConfig();
  config.kinds = distinctKinds();
  dog::Mapper original(config);
  const double origin_s = 77.0;
  runSteps(original, 0, 40, origin_s);
  original.finishStep();
  const std::string bytes = dog::serializeModel(original);
  EXPECT_EQ(getLE<std::uint8_t>(bytes, kLearnerOffset), 0);
  std::unique_ptr<dog::Mapper> loaded = roundTrip(original);
  ASSERT_NE(loaded, nullptr);
  EXPECT_EQ(loaded->config().learner, dog::TransitionLearner::kCellEm);
  expectSameFuture(original, *loaded, 40, 20, origin_s, -0.5, 0.5);
}

// ---- damaged files ---------------------------------------------------------------------------

TEST(ModelIoDamage, EveryTruncationIsRefused) {
  const std::string bytes = smallModel();
  ASSERT_NO_THROW(dog::deserializeModel(bytes));
  ASSERT_GT(getLE<std::uint64_t>(bytes, kCountOffset), 3U);
  for (std::size_t length = 0; length < bytes.size(); ++length) {
    const std::string message = errorOf(bytes.substr(0, length));
    ASSERT_TRUE(contains(message, "truncated")) << "length " << length << ": " << message;
    ASSERT_TRUE(contains(message, std::to_string(length) + " available")) << message;
  }
  EXPECT_EQ(errorOf(bytes.substr(0, 100)), "truncated model file: expected at least 20407 bytes, 100 available");
  const std::uint64_t count = getLE<std::uint64_t>(bytes, kCountOffset);
  EXPECT_EQ(errorOf(bytes.substr(0, bytes.size() - 1)),
            "truncated model file: expected " + std::to_string(bytes.size()) + " bytes for " + std::to_string(count) +
                " cells, " + std::to_string(bytes.size() - 1) + " available");
}

TEST(ModelIoDamage, EverySingleByteChangeIsRefused) {
  const std::string bytes = smallModel();
  for (std::size_t i = 0; i < bytes.size(); ++i) {
    for (const unsigned char flip : {0x01, 0x80, 0xFF}) {
      std::string damaged = bytes;
      damaged[i] = static_cast<char>(static_cast<unsigned char>(damaged[i]) ^ flip);
      const std::string message = errorOf(damaged);
      ASSERT_FALSE(contains(message, "NO EXCEPTION") || contains(message, "WRONG EXCEPTION"))
          << "byte " << i << " ^ " << int{flip} << ": " << message;
    }
  }
}

TEST(ModelIoDamage, MessagesSayWhatIsWrong) {
  const std::string bytes = smallModel();
  {
    std::string other = bytes;
    other[0] = 'X';
    EXPECT_TRUE(contains(errorOf(other), "not a dynamic_occupancy_grid model file")) << errorOf(other);
    EXPECT_TRUE(contains(errorOf("P5\n# a PGM image"), "not a dynamic_occupancy_grid model file"));
    EXPECT_TRUE(contains(errorOf("DOG"), "truncated"));
    EXPECT_TRUE(contains(errorOf(""), "truncated"));
  }
  {
    std::string newer = bytes;
    putLE<std::uint32_t>(newer, kVersionOffset, 4);
    fixChecksum(newer);
    EXPECT_EQ(errorOf(newer), "model format version 4, this build reads versions 1 to 3");
    putLE<std::uint32_t>(newer, kVersionOffset, 0);
    EXPECT_EQ(errorOf(newer), "model format version 0, this build reads versions 1 to 3");
  }
  {
    std::string corrupt = bytes;
    corrupt[kCellsOffset + 9] ^= 0x10;  // inside the first cell's p_occ
    EXPECT_TRUE(contains(errorOf(corrupt), "corrupt")) << errorOf(corrupt);
    EXPECT_TRUE(contains(errorOf(corrupt), "checksum")) << errorOf(corrupt);
  }
  {
    std::string longer = bytes + std::string(1, '\0');
    EXPECT_TRUE(contains(errorOf(longer), "1 trailing bytes")) << errorOf(longer);
    longer = bytes + bytes;
    EXPECT_TRUE(contains(errorOf(longer), "trailing")) << errorOf(longer);
  }
}

TEST(ModelIoDamage, AbsurdCellCountsAreRefusedBeforeAllocating) {
  const std::string bytes = smallModel();
  const std::uint64_t count = getLE<std::uint64_t>(bytes, kCountOffset);
  for (const std::uint64_t absurd :
       {count + 1, std::uint64_t{1} << 40, std::uint64_t{1} << 58,
        std::numeric_limits<std::uint64_t>::max() / kCellSize, std::numeric_limits<std::uint64_t>::max() / kCellSize + 1,
        std::numeric_limits<std::uint64_t>::max()}) {
    std::string damaged = bytes;
    putLE<std::uint64_t>(damaged, kCountOffset, absurd);
    fixChecksum(damaged);
    const std::string message = errorOf(damaged);
    EXPECT_TRUE(contains(message, "truncated") || contains(message, "absurd cell count")) << absurd << ": " << message;
  }
  std::string fewer = bytes;
  putLE<std::uint64_t>(fewer, kCountOffset, count - 1);
  fixChecksum(fewer);
  EXPECT_TRUE(contains(errorOf(fewer), "72 trailing bytes")) << errorOf(fewer);
}

TEST(ModelIoDamage, InvalidConfigurationIsRefusedWithValidatesMessage) {
  const std::string bytes = smallModel();
  const auto edited = [&bytes](auto edit) {
    std::string copy = bytes;
    edit(copy);
    fixChecksum(copy);
    return errorOf(copy);
  };
  std::string message = edited([](std::string& b) { putLE<double>(b, kResolutionOffset, -0.1); });
  EXPECT_TRUE(contains(message, "invalid configuration")) << message;
  EXPECT_TRUE(contains(message, "resolution")) << message;
  message = edited([](std::string& b) { putLE<double>(b, kPHitGivenOccOffset, 0.1); });  // below p_hit_given_free
  EXPECT_TRUE(contains(message, "invalid configuration")) << message;
  message = edited([](std::string& b) { putLE<double>(b, kInitialPOccOffset, std::nan("")); });
  EXPECT_TRUE(contains(message, "initial_p_occ")) << message;
  message = edited([](std::string& b) { putLE<std::uint32_t>(b, kMinObservedOffset, 70000); });
  EXPECT_TRUE(contains(message, "min_observed_steps")) << message;
  message = edited([](std::string& b) { putLE<double>(b, kMaxMapSizeOffset, 0.5); });  // below the fixed size
  EXPECT_TRUE(contains(message, "invalid configuration")) << message;
  // A boolean byte other than 0 or 1.
  for (const std::size_t offset : {kLearnOffset, kSymmetricOffset, kFixedOffset, kHasOriginOffset, kHasLastStepOffset}) {
    message = edited([offset](std::string& b) { b[offset] = 2; });
    EXPECT_TRUE(contains(message, "must be 0 or 1")) << offset << ": " << message;
  }
}

// Files written with the online EM's Robbins–Monro schedule or its averaging, or with the
// empirical-Bayes prior (options removed after a9ed7d5) still load: their cells go on with
// the 1/t schedule and the fixed prior. A schedule byte other than 0 or 1 is refused.
TEST(ModelIoFormat, FilesWithTheRemovedLearnerOptionsLoad) {
  const std::string bytes = smallModel();
  std::string robbins_monro = bytes;
  putLE<std::uint8_t>(robbins_monro, kLearnPriorOffset, 1);
  putLE<double>(robbins_monro, kLearnPriorOffset + 1, 7.0);
  putLE<std::uint8_t>(robbins_monro, kScheduleOffset, 1);
  putLE<double>(robbins_monro, kScheduleOffset + 1, 0.8);
  putLE<double>(robbins_monro, kScheduleOffset + 9, 3.0);
  putLE<std::uint32_t>(robbins_monro, kScheduleOffset + 17, 5);
  fixChecksum(robbins_monro);
  const std::unique_ptr<dog::Mapper> loaded = dog::deserializeModel(robbins_monro);
  ASSERT_NE(loaded, nullptr);
  EXPECT_EQ(dog::serializeModel(*loaded), bytes);
  putLE<std::uint8_t>(robbins_monro, kScheduleOffset, 2);
  fixChecksum(robbins_monro);
  EXPECT_TRUE(contains(errorOf(robbins_monro), "online_em.schedule is 2")) << errorOf(robbins_monro);
}

TEST(ModelIoDamage, InvalidTimeIsRefused) {
  const std::string bytes = smallModel();
  std::string damaged = bytes;
  damaged[kHasOriginOffset] = 0;  // a last step without a clock origin
  putLE<double>(damaged, kOriginOffset, 0.0);
  fixChecksum(damaged);
  EXPECT_TRUE(contains(errorOf(damaged), "invalid time")) << errorOf(damaged);
  damaged = bytes;
  putLE<double>(damaged, kOriginOffset, kInf);
  fixChecksum(damaged);
  EXPECT_TRUE(contains(errorOf(damaged), "invalid time")) << errorOf(damaged);
  damaged = bytes;
  putLE<std::int64_t>(damaged, kLastStepOffset, -5);
  fixChecksum(damaged);
  EXPECT_TRUE(contains(errorOf(damaged), "invalid time")) << errorOf(damaged);
  // An absent value must be stored as 0.
  dog::Mapper empty(fixedStaticConfig());
  damaged = dog::serializeModel(empty);
  putLE<std::int64_t>(damaged, kLastStepOffset, 3);
  fixChecksum(damaged);
  EXPECT_TRUE(contains(errorOf(damaged), "absent")) << errorOf(damaged);
}

TEST(ModelIoDamage, InvalidKindsAreRefused) {
  // The kinds' block of a map whose kinds learned (smallModel's learner is kinds).
  const std::string bytes = smallModel();
  ASSERT_EQ(getLE<std::uint8_t>(bytes, kLearnerOffset), 1);
  ASSERT_GT(getLE<double>(bytes, kKindCellsOffset), 0.0);
  const auto edited = [&bytes](auto edit) {
    std::string copy = bytes;
    edit(copy);
    fixChecksum(copy);
    return errorOf(copy);
  };
  EXPECT_EQ(edited([](std::string& b) { b[kLearnerOffset] = 2; }),
            "invalid model file: learner is 2, must be 0 (cell_em) or 1 (kinds)");
  for (const int kinds : {0, 4, 6, 255}) {
    EXPECT_EQ(edited([kinds](std::string& b) { b[kKindCountOffset] = static_cast<char>(kinds); }),
              "model file with " + std::to_string(kinds) + " kinds of cells, this build has 5");
  }
  EXPECT_EQ(edited([](std::string& b) { b[kKindSummaryOffset] = 3; }),
            "invalid model file: kinds.summary is 3, must be 0 (geometric_mean), 1 (mean) or 2 (most_probable)");
  EXPECT_EQ(edited([](std::string& b) { b[kKindCountingOffset] = 2; }),
            "invalid model file: kinds.counting is 2, must be 0 (posterior) or 1 (most_probable)");
  for (const int flag : {2, 255}) {
    EXPECT_EQ(edited([flag](std::string& b) { b[kKindLearnFromGapsOffset] = static_cast<char>(flag); }),
              "invalid model file: kinds.learn_from_gaps is " + std::to_string(flag) + ", must be 0 or 1");
  }
  // The distance bins of this build only (the second: 124 in the wrong byte order).
  for (const std::uint16_t bins : {0, 1, 123, 125, 31744, 65535}) {
    EXPECT_EQ(edited([bins](std::string& b) { putLE<std::uint16_t>(b, kKindBinCountOffset, bins); }),
              "model file with " + std::to_string(bins) + " distance bins of the kinds' pairs, this build has 124");
  }
  // Sums: every one negative, NaN or infinite (every pair of some bins, one pair of every bin).
  const std::string bad_sums =
      "invalid kinds of cells in model file: kinds: saved sums must be finite and >= 0, transitions within the bounds";
  std::vector<std::size_t> sums;
  for (std::size_t k = 0; k < 5; ++k) {
    for (const std::size_t bin : {std::size_t{0}, std::size_t{1}, std::size_t{16}, kKindBins - 1}) {
      for (std::size_t pair = 0; pair < 4; ++pair) {
        sums.push_back(kKindPairsOffset + 8 * ((k * kKindBins + bin) * 4 + pair));
      }
    }
  }
  for (std::size_t k = 0; k < 5; ++k) sums.push_back(kKindMembershipOffset + 8 * k);
  sums.push_back(kKindCellsOffset);
  for (const std::size_t offset : sums) {
    for (const double bad : {-1.0, -1e-300, std::nan(""), kInf}) {
      EXPECT_EQ(edited([offset, bad](std::string& b) { putLE<double>(b, offset, bad); }), bad_sums)
          << offset << " " << bad;
    }
  }
  for (std::size_t slot = 0; slot < 5 * kKindBins * 4; ++slot) {
    const double bad = slot % 2 == 0 ? std::nan("") : -0.5;
    ASSERT_EQ(edited([slot, bad](std::string& b) { putLE<double>(b, kKindPairsOffset + 8 * slot, bad); }), bad_sums)
        << "pair sum " << slot;
  }
  // The learned transitions: within [max(online_em.p_min, 1e-6), min(online_em.p_max, 0.5)].
  const dog::MapperConfig config = dog::deserializeModel(bytes)->config();
  const double low = std::max(config.online_em.p_min, 1e-6);
  const double high = std::min(config.online_em.p_max, 0.5);
  ASSERT_LT(low, high);
  for (std::size_t value = 0; value < 10; ++value) {
    const std::size_t offset = kKindTransitionsOffset + 8 * value;
    for (const double bad : {0.0, -0.1, std::nextafter(low, 0.0), std::nextafter(high, 1.0), 0.75, 1.0, std::nan(""),
                             kInf}) {
      EXPECT_EQ(edited([offset, bad](std::string& b) { putLE<double>(b, offset, bad); }), bad_sums)
          << "learned transition " << value << " = " << bad;
    }
    // The bounds themselves are learned transitions.
    for (const double good : {low, high}) {
      std::string copy = bytes;
      putLE<double>(copy, offset, good);
      fixChecksum(copy);
      EXPECT_EQ(errorOf(copy), "NO EXCEPTION") << "learned transition " << value << " = " << good;
    }
  }
  // The kinds' configuration passes KindsConfig::validate().
  std::string message = edited([](std::string& b) { putLE<double>(b, kKindInitialTransitionsOffset + 8, 0.75); });
  EXPECT_TRUE(contains(message, "invalid configuration in model file: kinds initial_transitions")) << message;
  message = edited([](std::string& b) { putLE<double>(b, kKindInitialWeightsOffset + 16, 0.5); });
  EXPECT_TRUE(contains(message, "invalid configuration in model file: kinds initial_weights must sum to 1")) << message;
  message = edited([](std::string& b) { putLE<double>(b, kKindTransitionPriorWeightOffset, 0.0); });
  EXPECT_TRUE(contains(message, "kinds transition_prior_weight")) << message;
  message = edited([](std::string& b) { putLE<double>(b, kKindWeightPriorCellsOffset, std::nan("")); });
  EXPECT_TRUE(contains(message, "kinds weight_prior_cells")) << message;
  message = edited([](std::string& b) { putLE<double>(b, kKindSwitchProbabilityOffset, 1.0); });
  EXPECT_TRUE(contains(message, "kinds switch_probability")) << message;
  message = edited([](std::string& b) { putLE<double>(b, kKindForgettingOffset, -0.5); });
  EXPECT_TRUE(contains(message, "kinds forgetting")) << message;
}

TEST(ModelIoDamage, InvalidCellsAreRefusedNamingTheCell) {
  const std::string bytes = smallModel();
  const std::int32_t x = getLE<std::int32_t>(bytes, kCellsOffset);
  const std::int32_t y = getLE<std::int32_t>(bytes, kCellsOffset + 4);
  const std::string first = "cell 0 at (" + std::to_string(x) + ", " + std::to_string(y) + ")";
  const auto edited = [&bytes](std::size_t field_offset, auto value) {
    std::string copy = bytes;
    putLE(copy, kCellsOffset + field_offset, value);
    fixChecksum(copy);
    return errorOf(copy);
  };
  for (const std::string& message :
       {edited(8, 1.5f), edited(8, std::nanf("")), edited(16, std::numeric_limits<float>::infinity()),
        edited(20, -0.25f), edited(24, 2.0f), edited(28, -1.0f), edited(56, std::nanf("")), edited(60, -1.0f),
        edited(64, std::numeric_limits<float>::infinity()),
        edited(12, std::int32_t{1000}) /* after the last applied step */,
        edited(12, dog::kNeverObserved)}) {
    EXPECT_TRUE(contains(message, "invalid model file: " + first)) << message;
  }
  // A cell outside the fixed bounds.
  std::string message = edited(0, std::int32_t{500});
  EXPECT_TRUE(contains(message, "cell 0 at (500, " + std::to_string(y) + ")")) << message;
  EXPECT_TRUE(contains(message, "outside")) << message;
  // The same cell twice.
  std::string twice = bytes;
  twice.replace(kCellsOffset + kCellSize, 8, bytes.substr(kCellsOffset, 8));
  fixChecksum(twice);
  EXPECT_TRUE(contains(errorOf(twice), "cell 1 at (" + std::to_string(x) + ", " + std::to_string(y) +
                                           ") appears twice"))
      << errorOf(twice);
}

TEST(ModelIoDamage, RandomGarbageNeverCrashes) {
  // Garbage with a valid magic, version and checksum: only runtime_errors (or a model).
  const std::string bytes = smallModel();
  std::mt19937 rng(99);
  for (int round = 0; round < 2000; ++round) {
    std::string garbage = bytes.substr(0, 12);
    const std::size_t length = rng() % (bytes.size() + 200);
    while (garbage.size() < length + 12) garbage.push_back(static_cast<char>(rng()));
    if (round % 2 == 0) {
      // Keep a plausible header now and then so the cell loop is reached.
      garbage.replace(0, std::min(garbage.size(), kCellsOffset), bytes.substr(0, std::min(garbage.size(), kCellsOffset)));
      if (garbage.size() >= kCellsOffset + 4) {
        putLE<std::uint64_t>(garbage, kCountOffset, (garbage.size() - kCellsOffset - 4) / kCellSize);
        garbage.resize(kCellsOffset + 4 + getLE<std::uint64_t>(garbage, kCountOffset) * kCellSize);
      }
    }
    if (garbage.size() >= 16) fixChecksum(garbage);
    try {
      dog::deserializeModel(garbage);
    } catch (const std::runtime_error&) {
    }
  }
}

// ---- files -------------------------------------------------------------------------------------

TEST(ModelIoFiles, SaveAndLoadAFile) {
  TempDir dir;
  dog::Mapper original(growingLearningConfig());
  runSteps(original, 0, 8, 5.0);
  original.finishStep();
  const std::string path = dir.file("model.dogm");
  dog::saveModel(original, path);
  EXPECT_EQ(readFile(path), dog::serializeModel(original));
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"model.dogm"});  // no temporary left
  std::unique_ptr<dog::Mapper> loaded = dog::loadModel(path);
  expectSameCells(original, *loaded);
  expectSameTime(original, *loaded);
  expectSameFuture(original, *loaded, 9, 4, 5.0);
}

TEST(ModelIoFiles, SavingReplacesAnOlderFile) {
  TempDir dir;
  const std::string path = dir.file("model.dogm");
  dog::Mapper first(growingLearningConfig());
  dog::saveModel(first, path);
  dog::Mapper second(fixedStaticConfig());
  runSteps(second, 0, 3, 1.0);
  second.finishStep();
  dog::saveModel(second, path);
  EXPECT_EQ(readFile(path), dog::serializeModel(second));
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"model.dogm"});
}

TEST(ModelIoFiles, LoadErrorsNameTheFile) {
  TempDir dir;
  const std::string missing = dir.file("missing.dogm");
  try {
    dog::loadModel(missing);
    FAIL() << "no exception";
  } catch (const std::runtime_error& error) {
    EXPECT_TRUE(contains(error.what(), missing)) << error.what();
    EXPECT_TRUE(contains(error.what(), "No such file")) << error.what();
  }
  const std::string directory = dir.file("a_directory");
  fs::create_directory(directory);
  try {
    dog::loadModel(directory);
    FAIL() << "no exception";
  } catch (const std::runtime_error& error) {
    EXPECT_TRUE(contains(error.what(), directory)) << error.what();
  }
  const std::string corrupt = dir.file("corrupt.dogm");
  std::string bytes = smallModel();
  bytes[kCellsOffset + 3] ^= 1;
  writeFile(corrupt, bytes);
  try {
    dog::loadModel(corrupt);
    FAIL() << "no exception";
  } catch (const std::runtime_error& error) {
    EXPECT_TRUE(contains(error.what(), corrupt)) << error.what();
    EXPECT_TRUE(contains(error.what(), "corrupt")) << error.what();
  }
  const std::string empty = dir.file("empty.dogm");
  writeFile(empty, "");
  try {
    dog::loadModel(empty);
    FAIL() << "no exception";
  } catch (const std::runtime_error& error) {
    EXPECT_TRUE(contains(error.what(), empty)) << error.what();
    EXPECT_TRUE(contains(error.what(), "truncated")) << error.what();
  }
}

TEST(ModelIoFiles, SavingIntoAMissingDirectoryThrowsNamingTheFile) {
  TempDir dir;
  const std::string path = dir.file("no/such/dir/model.dogm");
  dog::Mapper mapper(growingLearningConfig());
  try {
    dog::saveModel(mapper, path);
    FAIL() << "no exception";
  } catch (const std::runtime_error& error) {
    EXPECT_TRUE(contains(error.what(), path)) << error.what();
    EXPECT_TRUE(contains(error.what(), "No such file or directory")) << error.what();
  }
  EXPECT_TRUE(dir.entries().empty());
}

TEST(ModelIoFiles, FailedSaveKeepsTheOldFile_DirectoryNotWritable) {
  // No temporary can be created beside the file: the directory is read-only (as root, whom
  // permissions do not bind, the save runs as the user nobody).
  TempDir dir;
  const std::string path = dir.file("model.dogm");
  dog::Mapper old_mapper(fixedStaticConfig());
  dog::saveModel(old_mapper, path);
  const std::string old_bytes = readFile(path);
  dog::Mapper new_mapper(growingLearningConfig());
  runSteps(new_mapper, 0, 3, 0.0);
  new_mapper.finishStep();
  const fs::path directory = fs::path(path).parent_path();
  fs::permissions(directory, fs::perms::owner_read | fs::perms::owner_exec | fs::perms::group_read |
                                 fs::perms::group_exec | fs::perms::others_read | fs::perms::others_exec);
  const bool root = ::geteuid() == 0;
  if (root) ASSERT_EQ(::seteuid(65534), 0);
  std::string message = "NO EXCEPTION";
  try {
    dog::saveModel(new_mapper, path);
  } catch (const std::runtime_error& error) {
    message = error.what();
  }
  if (root) ASSERT_EQ(::seteuid(0), 0);
  fs::permissions(directory, fs::perms::owner_all, fs::perm_options::add);
  EXPECT_TRUE(contains(message, "cannot save model file " + path + ": cannot create a temporary file in ")) << message;
  EXPECT_TRUE(contains(message, "Permission denied")) << message;
  EXPECT_EQ(readFile(path), old_bytes);
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"model.dogm"});
  EXPECT_NO_THROW(dog::loadModel(path));
}

TEST(ModelIoFiles, FailedSaveKeepsTheOldFile_DiskFull) {
  // A full disk, simulated with a file size limit (RLIMIT_FSIZE; root is bound by it too):
  // writing the temporary fails part way; the old file stays, the temporary goes.
  TempDir dir;
  const std::string path = dir.file("model.dogm");
  dog::Mapper old_mapper(fixedStaticConfig());
  dog::saveModel(old_mapper, path);
  const std::string old_bytes = readFile(path);
  dog::Mapper new_mapper(growingLearningConfig());
  runSteps(new_mapper, 0, 5, 0.0);
  new_mapper.finishStep();
  const std::string new_bytes = dog::serializeModel(new_mapper);
  ASSERT_GT(new_bytes.size(), 20000U);

  rlimit saved_limit{};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &saved_limit), 0);
  if (saved_limit.rlim_max != RLIM_INFINITY && saved_limit.rlim_max < 20000) GTEST_SKIP() << "file size limit too low";
  const auto saved_handler = ::signal(SIGXFSZ, SIG_IGN);  // the write then fails with EFBIG
  rlimit small_limit = saved_limit;
  small_limit.rlim_cur = 10000;
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &small_limit), 0);
  std::string message = "NO EXCEPTION";
  try {
    dog::saveModel(new_mapper, path);
  } catch (const std::runtime_error& error) {
    message = error.what();
  }
  ::setrlimit(RLIMIT_FSIZE, &saved_limit);
  ::signal(SIGXFSZ, saved_handler);
  EXPECT_TRUE(contains(message, "cannot save model file " + path)) << message;
  EXPECT_TRUE(contains(message, "File too large")) << message;
  EXPECT_EQ(readFile(path), old_bytes);
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"model.dogm"});
  // And with room again, the save goes through.
  dog::saveModel(new_mapper, path);
  EXPECT_EQ(readFile(path), new_bytes);
}

// ---- files that are not model files: refused before anything is read or replaced ----------

namespace {

std::string loadErrorOf(const std::string& path) {
  try {
    dog::loadModel(path);
  } catch (const std::runtime_error& error) {
    return error.what();
  } catch (const std::exception& error) {
    return std::string("WRONG EXCEPTION TYPE: ") + error.what();
  }
  return "NO EXCEPTION";
}

std::string saveErrorOf(const std::string& path) {
  try {
    dog::Mapper mapper(growingLearningConfig());
    dog::saveModel(mapper, path);
  } catch (const std::runtime_error& error) {
    return error.what();
  }
  return "NO EXCEPTION";
}

// Seconds a call takes (on the steady clock).
template <class Fn>
double secondsOf(Fn&& fn) {
  const auto start = std::chrono::steady_clock::now();
  fn();
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

TEST(ModelIoSpecialFiles, AFifoIsRefusedAtOnce) {
  // Nobody writes to it: a plain open() would wait for a writer forever.
  TempDir dir;
  const std::string fifo = dir.file("fifo");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  std::string message;
  EXPECT_LT(secondsOf([&] { message = loadErrorOf(fifo); }), 2.0);
  EXPECT_EQ(message, "cannot load model file " + fifo + ": it is a FIFO (named pipe), not a regular file");
  // Saving to it neither blocks nor replaces it.
  EXPECT_LT(secondsOf([&] { message = saveErrorOf(fifo); }), 2.0);
  EXPECT_EQ(message, "cannot save model file " + fifo +
                         ": it is a FIFO (named pipe), not a regular file; it is left as it is");
  struct stat status {};
  ASSERT_EQ(::lstat(fifo.c_str(), &status), 0);
  EXPECT_TRUE(S_ISFIFO(status.st_mode));
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"fifo"});
}

TEST(ModelIoSpecialFiles, DevZeroIsRefusedWithoutReading) {
  // An endless file: reading "until the end" would allocate without bound.
  std::string message;
  EXPECT_LT(secondsOf([&] { message = loadErrorOf("/dev/zero"); }), 2.0);
  EXPECT_EQ(message, "cannot load model file /dev/zero: it is a character device, not a regular file");
  EXPECT_EQ(loadErrorOf("/dev/null"), "cannot load model file /dev/null: it is a character device, not a regular file");
}

TEST(ModelIoSpecialFiles, ADirectoryIsRefused) {
  TempDir dir;
  const std::string directory = dir.file("a_directory");
  fs::create_directory(directory);
  EXPECT_EQ(loadErrorOf(directory), "cannot load model file " + directory + ": it is a directory, not a regular file");
  EXPECT_EQ(saveErrorOf(directory),
            "cannot save model file " + directory + ": it is a directory, not a regular file; it is left as it is");
  EXPECT_TRUE(fs::is_directory(directory));
  EXPECT_TRUE(fs::is_empty(directory));
}

TEST(ModelIoSpecialFiles, DeviceNodesAreNeverReplaced) {
  // rename() over /dev/null would put a regular file in its place (as root: the system's).
  const std::string message = saveErrorOf("/dev/null");
  EXPECT_EQ(message, "cannot save model file /dev/null: it is a character device, not a regular file; it is left "
                     "as it is");
  struct stat status {};
  ASSERT_EQ(::stat("/dev/null", &status), 0);
  EXPECT_TRUE(S_ISCHR(status.st_mode));
  EXPECT_EQ(saveErrorOf("/dev/full"), "cannot save model file /dev/full: it is a character device, not a regular "
                                      "file; it is left as it is");
  // A device node of one's own (mknod needs CAP_MKNOD: root, outside some containers).
  TempDir dir;
  const std::string node = dir.file("null_device");
  if (::mknod(node.c_str(), S_IFCHR | 0600, ::makedev(1, 3)) != 0) GTEST_SKIP() << "mknod: " << std::strerror(errno);
  EXPECT_EQ(saveErrorOf(node), "cannot save model file " + node +
                                   ": it is a character device, not a regular file; it is left as it is");
  EXPECT_EQ(loadErrorOf(node), "cannot load model file " + node + ": it is a character device, not a regular file");
  ASSERT_EQ(::lstat(node.c_str(), &status), 0);
  EXPECT_TRUE(S_ISCHR(status.st_mode));
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"null_device"});
}

TEST(ModelIoSpecialFiles, SymbolicLinksAreFollowed) {
  // Loading a link loads the file it points to; saving to a link replaces that file (and
  // keeps the link); a link to something else, or to nothing, is refused as that is.
  TempDir dir;
  const std::string real = dir.file("real.dogm");
  dog::Mapper first(fixedStaticConfig());
  dog::saveModel(first, real);
  const std::string link = dir.file("current.dogm");
  fs::create_symlink(real, link);
  EXPECT_NO_THROW(dog::loadModel(link));
  dog::Mapper second(growingLearningConfig());
  runSteps(second, 0, 3, 0.0);
  second.finishStep();
  dog::saveModel(second, link);
  EXPECT_TRUE(fs::is_symlink(link));
  EXPECT_EQ(readFile(real), dog::serializeModel(second));
  EXPECT_EQ(dir.entries(), (std::vector<std::string>{"current.dogm", "real.dogm"}));

  const std::string to_device = dir.file("to_null.dogm");
  fs::create_symlink("/dev/null", to_device);
  EXPECT_EQ(saveErrorOf(to_device), "cannot save model file " + to_device +
                                        ": the symbolic link's target /dev/null is a character device, not a "
                                        "regular file; it is left as it is");
  EXPECT_EQ(loadErrorOf(to_device),
            "cannot load model file " + to_device + ": it is a character device, not a regular file");
  const std::string dangling = dir.file("dangling.dogm");
  fs::create_symlink(dir.file("nothing_here"), dangling);
  EXPECT_TRUE(contains(saveErrorOf(dangling), "it is a symbolic link that cannot be followed")) << saveErrorOf(dangling);
  EXPECT_TRUE(contains(loadErrorOf(dangling), "No such file or directory")) << loadErrorOf(dangling);
  EXPECT_FALSE(fs::exists(dir.file("nothing_here")));
}

TEST(ModelIoSpecialFiles, AHugeFileIsNotRead) {
  // A valid model followed by a terabyte (sparse: no disk used) of zeros: refused from its
  // size, nothing of it allocated or read.
  TempDir dir;
  const std::string path = dir.file("huge.dogm");
  const std::string bytes = smallModel();
  writeFile(path, bytes);
  const std::uint64_t huge = std::uint64_t{1} << 40;
  if (::truncate(path.c_str(), static_cast<off_t>(huge)) != 0) GTEST_SKIP() << "truncate: " << std::strerror(errno);
  const std::uint64_t count = getLE<std::uint64_t>(bytes, kCountOffset);
  std::string message;
  EXPECT_LT(secondsOf([&] { message = loadErrorOf(path); }), 2.0);
  EXPECT_EQ(message, "cannot load model file " + path + ": invalid model file: " +
                         std::to_string(huge - bytes.size()) + " trailing bytes after the checksum (" +
                         std::to_string(bytes.size()) + " bytes expected for " + std::to_string(count) + " cells)");
  // A header that promises a terabyte of cells in a small file: refused from the size too.
  std::string promising = bytes;
  putLE<std::uint64_t>(promising, kCountOffset, huge / kCellSize);
  fixChecksum(promising);
  writeFile(path, promising);
  EXPECT_EQ(loadErrorOf(path), "cannot load model file " + path + ": " + errorOf(promising));
  EXPECT_TRUE(contains(loadErrorOf(path), "truncated model file: expected")) << loadErrorOf(path);
}

TEST(ModelIoSpecialFiles, FileErrorsAreTheSerialisationsOwn) {
  // Reading a file in two steps (its header, then what the header promises) says exactly
  // what deserializeModel says of the same bytes: for every truncation and every byte
  // changed in the header, then for every 13th.
  TempDir dir;
  const std::string path = dir.file("damaged.dogm");
  const std::string bytes = smallModel();
  const auto expect_same = [&path](const std::string& content, const std::string& what) {
    // A new file each time (ext4 flushes a file truncated and rewritten when it is closed).
    writeFile(path, content);
    ASSERT_EQ(loadErrorOf(path), "cannot load model file " + path + ": " + errorOf(content)) << what;
    fs::remove(path);
  };
  const auto next = [](std::size_t i) { return i < kCellsOffset + 8 ? i + 1 : i + 13; };
  for (std::size_t length = 0; length < bytes.size(); length = next(length)) {
    expect_same(bytes.substr(0, length), "truncated");
  }
  expect_same(bytes.substr(0, bytes.size() - 1), "the last byte missing");
  for (std::size_t i = 0; i < bytes.size(); i = next(i)) {
    std::string damaged = bytes;
    damaged[i] = static_cast<char>(static_cast<unsigned char>(damaged[i]) ^ 0xFF);
    expect_same(damaged, "byte " + std::to_string(i));
  }
  expect_same(bytes + "x", "one trailing byte");
  expect_same(bytes + bytes, "twice");
  std::string version1 = bytes;
  putLE<std::uint32_t>(version1, kVersionOffset, 1);
  fixChecksum(version1);
  expect_same(version1, "version 1 layout of other bytes");
  std::string version2 = bytes;
  putLE<std::uint32_t>(version2, kVersionOffset, 2);
  fixChecksum(version2);
  expect_same(version2, "version 2 layout of other bytes");
  writeFile(path, bytes);
  EXPECT_NO_THROW(dog::loadModel(path));
}
