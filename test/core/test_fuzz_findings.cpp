// Regression tests for what fuzzing found (test/fuzz, docs/reliability.md), one per finding,
// each at the unit whose rule was missing:
//   - model_io: a model file whose header (fixed bounds) or whose cells (two far apart) ask
//     for a tile index of gigabytes is refused before anything is allocated;
//   - mapper: after restartClockAt, a scan stamped before step 0 is late
//     (kRejectedTimeBackwards), however far before;
//   - scan_beams: finite angles whose beam headings overflow to infinity are refused.

#include <gtest/gtest.h>
#include <zlib.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/layers/model_io.h"
#include "dynamic_occupancy_grid/core/grid/scan_beams.h"

namespace dog = dynamic_occupancy_grid::core;

namespace {

// docs/model_format.md: offsets in the version 3 header, its size, and the cell records' size.
constexpr std::size_t kFixedBoundsOffset = 146;
constexpr std::size_t kWidthOffset = 147;
constexpr std::size_t kHeightOffset = 155;
constexpr std::size_t kMaxMapSizeOffset = 163;
constexpr std::size_t kHeaderSize = 20403;
constexpr std::size_t kCellSize = 72;

void putDouble(std::string& bytes, std::size_t offset, double value) {
  std::uint64_t bits;
  std::memcpy(&bits, &value, sizeof(bits));
  for (int k = 0; k < 8; ++k) bytes[offset + k] = static_cast<char>((bits >> (8 * k)) & 0xff);
}

void putInt32(std::string& bytes, std::size_t offset, std::int32_t value) {
  const auto bits = static_cast<std::uint32_t>(value);
  for (int k = 0; k < 4; ++k) bytes[offset + k] = static_cast<char>((bits >> (8 * k)) & 0xff);
}

void fixChecksum(std::string& bytes) {
  const std::size_t body = bytes.size() - 4;
  const auto crc = static_cast<std::uint32_t>(
      ::crc32_z(::crc32_z(0L, nullptr, 0), reinterpret_cast<const unsigned char*>(bytes.data()), body));
  for (int k = 0; k < 4; ++k) bytes[body + k] = static_cast<char>((crc >> (8 * k)) & 0xff);
}

std::string refusal(const std::string& bytes) {
  try {
    dog::deserializeModel(bytes);
  } catch (const std::runtime_error& error) {
    return error.what();
  }
  return "";
}

dog::Scan scanAt(double stamp_s, double yaw_rad = 0.0, double angle_min_rad = -0.5,
                 double angle_increment_rad = 0.25) {
  dog::Scan scan;
  scan.stamp_s = stamp_s;
  scan.laser_pose = dog::Pose2D{0.0, 0.0, yaw_rad};
  scan.angle_min_rad = angle_min_rad;
  scan.angle_increment_rad = angle_increment_rad;
  scan.range_min_m = 0.1;
  scan.range_max_m = 5.0;
  scan.ranges_m = {1.0f, 2.0f, 3.0f, 2.5f, 1.5f};
  return scan;
}

}  // namespace

// Fuzzing found a 276-byte file that made the reader allocate 7.8 GB: a fixed-bounds
// header asking for a 40 km square at 5 cm (within max_map_size's 1e8 cells per side).
TEST(FuzzFindings, ModelWhoseFixedBoundsNeedAHugeTileIndexIsRefused) {
  dog::MapperConfig config;
  config.resolution_m = 0.05;
  config.fixed_bounds = true;
  config.width_m = 10.0;
  config.height_m = 10.0;
  config.max_map_size_m = 10.0;
  std::string bytes = dog::serializeModel(dog::Mapper(config));
  ASSERT_EQ(bytes[kFixedBoundsOffset], 1);
  for (const std::size_t offset : {kWidthOffset, kHeightOffset, kMaxMapSizeOffset}) putDouble(bytes, offset, 40000.0);
  fixChecksum(bytes);
  EXPECT_NE(refusal(bytes).find("tile index"), std::string::npos) << refusal(bytes);

  // A large map that a machine holds still loads: 1 km square at 5 cm (a 0.8 MB index).
  for (const std::size_t offset : {kWidthOffset, kHeightOffset, kMaxMapSizeOffset}) putDouble(bytes, offset, 1000.0);
  fixChecksum(bytes);
  EXPECT_EQ(refusal(bytes), "");
}

// The same through the cells of a growing map: two cells 390 000 cells apart on both axes.
TEST(FuzzFindings, ModelWhoseCellsSpanAHugeTileIndexIsRefused) {
  dog::MapperConfig config;
  config.resolution_m = 0.05;
  config.max_map_size_m = 40000.0;
  dog::Mapper mapper(config);
  ASSERT_EQ(mapper.integrate(scanAt(1.0)).status, dog::ScanStatus::kIntegrated);
  mapper.finishStep();
  std::string bytes = dog::serializeModel(mapper);
  ASSERT_GE(bytes.size(), kHeaderSize + 2 * kCellSize + 4);
  const std::size_t last_cell = bytes.size() - 4 - kCellSize;
  putInt32(bytes, last_cell, 390000);
  putInt32(bytes, last_cell + 4, 390000);
  fixChecksum(bytes);
  EXPECT_NE(refusal(bytes).find("tile index"), std::string::npos) << refusal(bytes);
}

// Fuzzing the node's scan path: the clock restarted at a scan the Mapper then refused
// (MappingNode restarts before integrating), and the next scan was stamped a little before
// it. It went into step -1; one stamped far before went into a step below INT32_MIN.
TEST(FuzzFindings, ScanBeforeStepZeroAfterRestartClockAtIsLate) {
  dog::Mapper mapper{dog::MapperConfig{}};
  mapper.restartClockAt(100.0);
  for (const double stamp_s : {99.5, 100.0 - 1.0e12}) {
    const dog::ScanResult result = mapper.integrate(scanAt(stamp_s));
    EXPECT_EQ(result.status, dog::ScanStatus::kRejectedTimeBackwards) << stamp_s << ": " << result.error;
  }
  EXPECT_EQ(mapper.integrate(scanAt(100.2)).status, dog::ScanStatus::kIntegrated);
  mapper.finishStep();
  EXPECT_EQ(mapper.lastAppliedStep(), std::optional<std::int64_t>(0));

  // The same once steps were applied: the first allowed step is the next one.
  mapper.restartClockAt(50.0);
  EXPECT_EQ(mapper.integrate(scanAt(49.0)).status, dog::ScanStatus::kRejectedTimeBackwards);
  EXPECT_EQ(mapper.integrate(scanAt(50.0)).status, dog::ScanStatus::kIntegrated);
}

// Fuzzing the scan path: finite angle_min, angle_increment and yaw whose sum for some beam
// is infinite gave NaN beam ends (cos(inf)), cast to int32 (undefined behaviour).
TEST(FuzzFindings, BeamHeadingsThatOverflowAreRefused) {
  const double huge = std::numeric_limits<double>::max() / 2.0;
  const std::vector<dog::Scan> scans = {
      scanAt(1.0, 0.0, 0.0, huge),          // the last beams' angles overflow
      scanAt(1.0, huge * 1.5, huge, 0.25),  // yaw + angle_min overflows
      scanAt(1.0, huge * 1.5, 0.0, huge * 0.4),  // only the last beams' headings overflow
  };
  for (const dog::Scan& scan : scans) {
    const auto error = dog::scanFieldsError(scan);
    ASSERT_TRUE(error.has_value());
    EXPECT_NE(error->find("beam headings"), std::string::npos) << *error;
    dog::Mapper mapper{dog::MapperConfig{}};
    EXPECT_EQ(mapper.integrate(scan).status, dog::ScanStatus::kRejectedInvalid);
  }
  // Large but finite headings are fine (cos and sin reduce them).
  EXPECT_FALSE(dog::scanFieldsError(scanAt(1.0, 1.0e300, -1.0e300, 0.25)).has_value());
}
