// libFuzzer target: the bag scan source (ros/bag_scan_source.h). Each input is turned into a
// small bag, written by rosbag: scans (header stamps, frames and every LaserScan field as raw
// float bits, so NaN and infinities appear), /tf and /tf_static transforms (frames from a few
// names, values as raw double bits), each recorded at its own bag time, on /scan or another
// topic; then BagScanSource reads it with options from the input (time range, tf lookahead,
// maximum range, a static laser pose or tf), and the scans it hands out go into a Mapper,
// as process_bag does. BagScanSource may refuse a bag with std::runtime_error (documented);
// any other exception is a finding (uncaught, it aborts).
//
// The bag is written by rosbag rather than taken from raw bytes: fuzzing rosbag's own parser
// found two bugs of Debian's ROS libraries within a minute (docs/reliability.md), which
// would keep this target from reaching the code of this package.

#include <fuzzer/FuzzedDataProvider.h>
#include <geometry_msgs/TransformStamped.h>
#include <ros/package.h>
#include <rosbag/bag.h>
#include <sensor_msgs/LaserScan.h>
#include <tf2_msgs/TFMessage.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <string>

#include "dynamic_occupancy_grid/core/grid/mapper.h"
#include "dynamic_occupancy_grid/ros/bag_scan_source.h"
#include "scratch_file.h"

namespace core = dynamic_occupancy_grid::core;
namespace ros_layer = dynamic_occupancy_grid::ros_layer;

namespace {

constexpr int kMaxMessages = 24;
constexpr std::size_t kMaxRanges = 64;
const char* const kFrames[] = {"odom", "base_link", "laser", "/laser", "map", ""};
const char* const kScanTopics[] = {"/scan", "scan_other"};

[[noreturn]] void fail(const char* what) {
  std::fprintf(stderr, "fuzz_bag_scan_source: %s\n", what);
  std::abort();
}

const std::string& bagPath() {
  static const std::string path = [] {
    // /dev/shm when there is one: a bag per input, written and read in memory.
    std::string file = fuzz_scratch::makeFile(
        {"/dev/shm/fuzz_bag_scan_source.XXXXXX", "/tmp/fuzz_bag_scan_source.XXXXXX"}, "input.bag");
    if (file.empty()) fail("cannot create a temporary directory");
    return file;
  }();
  return path;
}

template <class Float, class Bits>
Float fromBits(FuzzedDataProvider& input) {
  const Bits bits = input.ConsumeIntegral<Bits>();
  Float value;
  std::memcpy(&value, &bits, sizeof(value));
  return value;
}
float rawFloat(FuzzedDataProvider& input) { return fromBits<float, std::uint32_t>(input); }
double rawDouble(FuzzedDataProvider& input) { return fromBits<double, std::uint64_t>(input); }

ros::Time timeFrom(FuzzedDataProvider& input) {
  // rosbag records times from 1 ns on; a few thousand seconds keep stamps near each other.
  return ros::Time(input.ConsumeIntegralInRange<std::uint32_t>(1, 3000),
                   input.ConsumeIntegralInRange<std::uint32_t>(0, 999999999));
}

std::string frameFrom(FuzzedDataProvider& input) { return input.PickValueInArray(kFrames); }

sensor_msgs::LaserScan scanFrom(FuzzedDataProvider& input) {
  sensor_msgs::LaserScan scan;
  scan.header.stamp = timeFrom(input);
  scan.header.frame_id = frameFrom(input);
  scan.angle_min = rawFloat(input);
  scan.angle_max = rawFloat(input);
  scan.angle_increment = rawFloat(input);
  scan.range_min = rawFloat(input);
  scan.range_max = rawFloat(input);
  const std::size_t count = input.ConsumeIntegralInRange<std::size_t>(0, kMaxRanges);
  for (std::size_t i = 0; i < count && input.remaining_bytes() >= sizeof(float); ++i) {
    scan.ranges.push_back(rawFloat(input));
  }
  return scan;
}

tf2_msgs::TFMessage transformsFrom(FuzzedDataProvider& input) {
  tf2_msgs::TFMessage message;
  const int count = input.ConsumeIntegralInRange<int>(1, 3);
  for (int k = 0; k < count; ++k) {
    geometry_msgs::TransformStamped transform;
    transform.header.stamp = timeFrom(input);
    transform.header.frame_id = frameFrom(input);
    transform.child_frame_id = frameFrom(input);
    transform.transform.translation.x = rawDouble(input);
    transform.transform.translation.y = rawDouble(input);
    transform.transform.translation.z = rawDouble(input);
    transform.transform.rotation.x = rawDouble(input);
    transform.transform.rotation.y = rawDouble(input);
    transform.transform.rotation.z = rawDouble(input);
    transform.transform.rotation.w = rawDouble(input);
    message.transforms.push_back(transform);
  }
  return message;
}

void writeBag(FuzzedDataProvider& input) {
  rosbag::Bag bag(bagPath(), rosbag::bagmode::Write);
  const int messages = input.ConsumeIntegralInRange<int>(0, kMaxMessages);
  for (int m = 0; m < messages && input.remaining_bytes() > 0; ++m) {
    const ros::Time recorded = timeFrom(input);
    switch (input.ConsumeIntegralInRange<int>(0, 2)) {
      case 0:
        bag.write(input.PickValueInArray(kScanTopics), recorded, scanFrom(input));
        break;
      case 1:
        bag.write("/tf", recorded, transformsFrom(input));
        break;
      default:
        bag.write("/tf_static", recorded, transformsFrom(input));
        break;
    }
  }
}

ros_layer::BagScanSourceOptions optionsFrom(FuzzedDataProvider& input) {
  ros_layer::BagScanSourceOptions options;
  options.bag_path = bagPath();
  options.scan_topic = input.ConsumeBool() ? "/scan" : "scan";
  options.fixed_frame = input.ConsumeBool() ? "odom" : "/map";
  options.start_time_s = input.ConsumeBool() ? 0.0 : input.ConsumeFloatingPointInRange<double>(-1.0, 3000.0);
  options.end_time_s = input.ConsumeBool() ? 0.0 : input.ConsumeFloatingPointInRange<double>(-1.0, 3000.0);
  options.tf_lookahead_s = input.ConsumeFloatingPointInRange<double>(-1.0, 100.0);
  options.max_range_m = input.ConsumeBool() ? 20.0 : rawDouble(input);
  if (input.ConsumeBool()) options.static_laser_pose = core::Pose2D{rawDouble(input), rawDouble(input), 0.3};
  return options;
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  // Every rosbag::Bag loads rosbag's encryption plugins through pluginlib, which reads the
  // manifest of every package on ROS_PACKAGE_PATH: 10-20 ms per bag with a full ROS install.
  // rosbag_storage's own are all it needs.
  const std::string rosbag_storage = ros::package::getPath("rosbag_storage");
  if (rosbag_storage.empty()) fail("rosbag_storage not found (its encryption plugins are needed)");
  ::setenv("ROS_PACKAGE_PATH", rosbag_storage.c_str(), 1);
  // One bag kept for the process keeps the plugins' library loaded: otherwise every bag
  // loads and unloads it, and each unload gets slower (__cxa_finalize).
  static const rosbag::Bag keeps_plugins_loaded;
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  FuzzedDataProvider input(data, size);
  ros_layer::BagScanSourceOptions options = optionsFrom(input);
  writeBag(input);

  // A coarse, small map (at most 4 tiles): the bag source is the unit under test here.
  core::MapperConfig config;
  config.resolution_m = 0.5;
  config.max_map_size_m = 32.0;
  core::Mapper mapper(config);
  try {
    ros_layer::BagScanSource source(std::move(options));
    source.forEachScan([&mapper](const core::Scan& scan) { mapper.integrate(scan); });
  } catch (const std::runtime_error&) {
    // A bag without the topic, a bad time range, ...: refused with a message, as documented.
  }
  return 0;
}
