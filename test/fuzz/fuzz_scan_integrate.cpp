// libFuzzer target: LaserScan messages and laser transforms -> the node's conversions
// (ros/conversions.h: checkScanShape, toLaserPose, toCoreScan) -> Mapper::integrate, as
// MappingNode's scan callback does it, including its restart of the map's clock when time
// jumps back. The input is a sequence of operations: a scan (header stamp, the LaserScan's
// fields and ranges as raw float bits, so NaN and infinities appear, and the transform as
// raw double bits), finishStep, or a restart of the clock. At the end the map must save,
// load and save again to the same bytes.

#include <fuzzer/FuzzedDataProvider.h>
#include <geometry_msgs/Transform.h>
#include <sensor_msgs/LaserScan.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <optional>
#include <string>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/core/layers/model_io.h"
#include "dynamic_occupancy_grid/ros/conversions.h"

namespace core = dynamic_occupancy_grid::core;
namespace ros_layer = dynamic_occupancy_grid::ros_layer;

namespace {

// The node's default ~time_jump_threshold (s) and a small ~max_range (m).
constexpr double kTimeJumpThresholdS = 1.0;
constexpr double kMaxRangeM = 30.0;
constexpr int kMaxOperations = 24;
constexpr std::size_t kMaxRanges = 1080;

template <class Float, class Bits>
Float fromBits(FuzzedDataProvider& input) {
  const Bits bits = input.ConsumeIntegral<Bits>();
  Float value;
  std::memcpy(&value, &bits, sizeof(value));
  return value;
}
float rawFloat(FuzzedDataProvider& input) { return fromBits<float, std::uint32_t>(input); }
double rawDouble(FuzzedDataProvider& input) { return fromBits<double, std::uint64_t>(input); }

core::MapperConfig configFrom(FuzzedDataProvider& input) {
  core::MapperConfig config;
  // A small map (at most 4 tiles of 64 x 64 cells): a tile costs 280 kB to allocate and
  // clear, and a larger map would only cost more time per input.
  const double resolutions_m[] = {0.2, 0.5, 1.0};
  config.resolution_m = resolutions_m[input.ConsumeIntegralInRange<int>(0, 2)];
  config.time_step_s = input.ConsumeBool() ? 1.0 : 0.1;
  config.max_map_size_m = 12.8;
  config.max_free_range_m = input.ConsumeBool() ? 0.0 : 20.0;
  config.learn_transitions = input.ConsumeBool();
  config.learn_sensor_model = input.ConsumeBool();
  if (input.ConsumeBool()) {
    config.fixed_bounds = true;
    config.origin_x_m = -5.0;
    config.origin_y_m = -5.0;
    config.width_m = 10.0;
    config.height_m = 10.0;
  }
  return config;
}

sensor_msgs::LaserScan scanFrom(FuzzedDataProvider& input) {
  sensor_msgs::LaserScan msg;
  msg.header.frame_id = "laser";
  msg.header.stamp.sec = input.ConsumeIntegralInRange<std::uint32_t>(0, 4000);
  msg.header.stamp.nsec = input.ConsumeIntegralInRange<std::uint32_t>(0, 999999999);
  msg.angle_min = rawFloat(input);
  msg.angle_max = rawFloat(input);
  msg.angle_increment = rawFloat(input);
  msg.range_min = rawFloat(input);
  msg.range_max = rawFloat(input);
  const std::size_t count = input.ConsumeIntegralInRange<std::size_t>(0, kMaxRanges);
  for (std::size_t i = 0; i < count && input.remaining_bytes() >= sizeof(float); ++i) {
    msg.ranges.push_back(rawFloat(input));
  }
  return msg;
}

geometry_msgs::Transform transformFrom(FuzzedDataProvider& input) {
  geometry_msgs::Transform transform;
  transform.translation.x = rawDouble(input);
  transform.translation.y = rawDouble(input);
  transform.rotation.x = rawDouble(input);
  transform.rotation.y = rawDouble(input);
  transform.rotation.z = rawDouble(input);
  transform.rotation.w = rawDouble(input);
  return transform;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  FuzzedDataProvider input(data, size);
  core::Mapper mapper(configFrom(input));
  std::optional<double> newest_stamp_s;
  for (int operation = 0; operation < kMaxOperations && input.remaining_bytes() > 0; ++operation) {
    switch (input.ConsumeIntegralInRange<int>(0, 7)) {
      case 0:
        mapper.finishStep();
        break;
      case 1:
        mapper.restartClockAt(input.ConsumeIntegralInRange<std::uint32_t>(0, 4000));
        newest_stamp_s.reset();
        break;
      default: {
        const sensor_msgs::LaserScan msg = scanFrom(input);
        const geometry_msgs::Transform transform = transformFrom(input);
        // MappingNode::scanCallback's order of checks.
        if (msg.header.stamp.isZero()) break;
        std::string error;
        if (!ros_layer::checkScanShape(msg, &error)) break;
        core::Pose2D pose;
        bool upside_down = false;
        if (!ros_layer::toLaserPose(transform, &pose, &upside_down, &error)) break;
        core::Scan scan = ros_layer::toCoreScan(msg, pose, upside_down);
        scan.range_max_m = std::min(scan.range_max_m, kMaxRangeM);
        if (newest_stamp_s && scan.stamp_s < *newest_stamp_s - kTimeJumpThresholdS) {
          mapper.restartClockAt(scan.stamp_s);
          newest_stamp_s.reset();
        }
        const core::ScanResult result = mapper.integrate(scan);
        if (result.status == core::ScanStatus::kIntegrated) {
          newest_stamp_s = std::max(newest_stamp_s.value_or(scan.stamp_s), scan.stamp_s);
        }
        break;
      }
    }
  }
  mapper.finishStep();
  const std::string saved = core::serializeModel(mapper);
  if (core::serializeModel(*core::deserializeModel(saved)) != saved) {
    std::fprintf(stderr, "fuzz_scan_integrate: the map saved, loaded and saved again changed\n");
    std::abort();
  }
  return 0;
}
