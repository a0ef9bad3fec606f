#include "dynamic_occupancy_grid/ros/bag_scan_source.h"

#include <rosbag/bag.h>
#include <rosbag/exceptions.h>
#include <rosbag/view.h>
#include <sensor_msgs/LaserScan.h>
#include <tf2/buffer_core.h>
#include <tf2/exceptions.h>
#include <tf2_msgs/TFMessage.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <exception>
#include <filesystem>
#include <set>
#include <stdexcept>
#include <utility>
#include <vector>

#include "dynamic_occupancy_grid/ros/conversions.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {
namespace {

const std::string kTfTopic = "/tf";
const std::string kTfStaticTopic = "/tf_static";
const std::string kLaserScanType = "sensor_msgs/LaserScan";

// How often forEachScan reports progress (and so how soon a cancellation is seen).
constexpr std::chrono::milliseconds kProgressPeriod{20};

// Transforms older than this (before the newest one read) are dropped from the buffer. A
// scan is looked up tf_lookahead_s of recording time after it was recorded, so a scan
// whose stamp lags its recording time by less than this margin finds its pose.
constexpr double kTfCacheMargin_s = 60.0;

std::string withLeadingSlash(const std::string& topic) {
  return (!topic.empty() && topic.front() == '/') ? topic : "/" + topic;
}

std::string withoutLeadingSlash(const std::string& frame) {
  return (!frame.empty() && frame.front() == '/') ? frame.substr(1) : frame;
}

// Our own errors inside a try block that turns everything else into "corrupt bag" (they
// already say what is wrong and name the file).
struct SourceError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Thrown through the reading loop to carry an exception of the caller's callback past the
// handlers that turn the bag's own errors into "corrupt bag" messages.
struct CallbackFailed {
  std::exception_ptr error;
};

std::string laserScanTopics(const rosbag::Bag& bag) {
  rosbag::View all(bag);
  std::set<std::string> topics;
  for (const rosbag::ConnectionInfo* connection : all.getConnections()) {
    if (connection->datatype == kLaserScanType) topics.insert(connection->topic);
  }
  if (topics.empty()) return "none";
  std::string list;
  for (const std::string& topic : topics) list += (list.empty() ? "" : ", ") + topic;
  return list;
}

}  // namespace

struct BagScanSource::Impl {
  rosbag::Bag bag;
  std::vector<geometry_msgs::TransformStamped> static_transforms;
  bool has_tf_messages = false;  ///< on /tf: scans must wait for the transforms after them
  double duration_s = 0.0;
};

BagScanSource::BagScanSource(BagScanSourceOptions options)
    : options_(std::move(options)), impl_(std::make_unique<Impl>()) {
  options_.scan_topic = withLeadingSlash(options_.scan_topic);
  options_.fixed_frame = withoutLeadingSlash(options_.fixed_frame);
  const std::string& path = options_.bag_path;
  if (!std::isfinite(options_.start_time_s) || !std::isfinite(options_.end_time_s) ||
      options_.start_time_s < 0.0 || options_.end_time_s < 0.0 ||
      (options_.end_time_s > 0.0 && options_.end_time_s < options_.start_time_s)) {
    throw std::runtime_error("bad time range for bag " + path + ": start " + std::to_string(options_.start_time_s) +
                             " s, end " + std::to_string(options_.end_time_s) +
                             " s (need 0 <= start <= end, 0 = unbounded)");
  }
  if (!std::isfinite(options_.tf_lookahead_s) || options_.tf_lookahead_s < 0.0) {
    throw std::runtime_error("tf lookahead must be >= 0 s, got " + std::to_string(options_.tf_lookahead_s));
  }
  std::error_code error;
  if (!std::filesystem::exists(path, error)) throw std::runtime_error("bag " + path + " does not exist");
  if (std::filesystem::is_directory(path, error)) throw std::runtime_error("bag " + path + " is a directory, not a file");
  try {
    impl_->bag.open(path, rosbag::bagmode::Read);
  } catch (const std::exception& e) {
    throw std::runtime_error("cannot read bag " + path + " (truncated, corrupt or not a bag?): " + e.what());
  }
  try {
    rosbag::View scans(impl_->bag, rosbag::TopicQuery(options_.scan_topic));
    if (scans.size() == 0) {
      throw SourceError("bag " + path + " has no messages on topic " + options_.scan_topic +
                        " (LaserScan topics in it: " + laserScanTopics(impl_->bag) + ")");
    }
    for (const rosbag::ConnectionInfo* connection : scans.getConnections()) {
      if (connection->datatype != kLaserScanType) {
        throw SourceError("topic " + options_.scan_topic + " in bag " + path + " holds " + connection->datatype +
                          ", not " + kLaserScanType);
      }
    }
    impl_->duration_s = (scans.getEndTime() - scans.getBeginTime()).toSec();
    if (options_.static_laser_pose) return;

    rosbag::View tf_view(impl_->bag, rosbag::TopicQuery(std::vector<std::string>{kTfTopic, kTfStaticTopic}));
    if (tf_view.size() == 0) {
      throw SourceError("bag " + path + " has no /tf or /tf_static messages: the pose of the laser in '" +
                        options_.fixed_frame +
                        "' is unknown (a bag without tf needs a static laser pose: --laser-pose in the bag tools)");
    }
    impl_->has_tf_messages = rosbag::View(impl_->bag, rosbag::TopicQuery(kTfTopic)).size() > 0;
    // Static transforms hold for the whole bag, wherever they were recorded.
    rosbag::View static_view(impl_->bag, rosbag::TopicQuery(kTfStaticTopic));
    for (const rosbag::MessageInstance& message : static_view) {
      const tf2_msgs::TFMessage::ConstPtr transforms = message.instantiate<tf2_msgs::TFMessage>();
      if (!transforms) continue;
      impl_->static_transforms.insert(impl_->static_transforms.end(), transforms->transforms.begin(),
                                      transforms->transforms.end());
    }
  } catch (const SourceError&) {
    throw;
  } catch (const std::exception& e) {
    throw SourceError("bag " + path + " is corrupt: " + e.what());
  }
}

BagScanSource::~BagScanSource() = default;

BagScanStats BagScanSource::forEachScan(const std::function<void(const core::Scan&)>& on_scan,
                                        const BagReadProgress& on_progress) {
  BagScanStats stats;
  stats.bag_duration_s = impl_->duration_s;
  const bool use_tf = !options_.static_laser_pose;
  const double start_s = options_.start_time_s;
  const double end_s = options_.end_time_s > 0.0 ? options_.end_time_s : INFINITY;

  std::unique_ptr<tf2::BufferCore> tf;
  if (use_tf) {
    tf = std::make_unique<tf2::BufferCore>(ros::Duration(kTfCacheMargin_s + 2.0 * options_.tf_lookahead_s));
    for (const geometry_msgs::TransformStamped& transform : impl_->static_transforms) {
      tf->setTransform(transform, "bag", true);
    }
  }

  std::optional<double> first_bag_time_s;
  std::optional<double> last_bag_time_s;
  // Hands a scan whose transforms have been read to the caller.
  const auto deliver = [&](const sensor_msgs::LaserScan& msg) {
    core::Pose2D pose;
    bool upside_down = false;
    if (options_.static_laser_pose) {
      pose = *options_.static_laser_pose;
    } else {
      try {
        const geometry_msgs::TransformStamped transform = tf->lookupTransform(
            options_.fixed_frame, withoutLeadingSlash(msg.header.frame_id), msg.header.stamp);
        std::string error;
        if (!toLaserPose(transform.transform, &pose, &upside_down, &error)) throw tf2::TransformException(error);
      } catch (const tf2::TransformException& e) {
        ++stats.scans_without_pose;
        stats.last_pose_error = e.what();
        return;
      }
    }
    const double stamp_s = msg.header.stamp.toSec();
    if (!stats.first_stamp_s) stats.first_stamp_s = stamp_s;
    stats.last_stamp_s = stamp_s;
    try {
      core::Scan scan = toCoreScan(msg, pose, upside_down);
      scan.range_max_m = std::min(scan.range_max_m, options_.max_range_m);
      on_scan(std::move(scan));
    } catch (...) {
      throw CallbackFailed{std::current_exception()};
    }
  };

  struct PendingScan {
    sensor_msgs::LaserScan::ConstPtr msg;
    double bag_time_s;
  };
  std::deque<PendingScan> pending;  // scans waiting for the transforms recorded after them
  auto last_report = std::chrono::steady_clock::now();
  const auto report = [&](double fraction) {
    if (!on_progress) return true;
    last_report = std::chrono::steady_clock::now();
    return on_progress(std::clamp(fraction, 0.0, 1.0));
  };

  try {
    std::vector<std::string> topics{options_.scan_topic};
    if (use_tf) topics.push_back(kTfTopic);
    rosbag::View view(impl_->bag, rosbag::TopicQuery(topics));
    const double begin_s = view.getBeginTime().toSec();
    const double span_s = (view.getEndTime() - view.getBeginTime()).toSec();
    if (!report(0.0)) {
      stats.cancelled = true;
      return stats;
    }
    for (const rosbag::MessageInstance& message : view) {
      const double bag_time_s = message.getTime().toSec();
      if (on_progress && std::chrono::steady_clock::now() - last_report >= kProgressPeriod &&
          !report(span_s > 0.0 ? (bag_time_s - begin_s) / span_s : 0.0)) {
        stats.cancelled = true;
        return stats;
      }
      const bool is_tf = use_tf && message.getTopic() == kTfTopic;
      if (is_tf) {
        const tf2_msgs::TFMessage::ConstPtr transforms = message.instantiate<tf2_msgs::TFMessage>();
        if (transforms) {
          for (const geometry_msgs::TransformStamped& transform : transforms->transforms) {
            tf->setTransform(transform, "bag", false);
          }
        }
      }
      while (!pending.empty() && bag_time_s > pending.front().bag_time_s + options_.tf_lookahead_s) {
        deliver(*pending.front().msg);
        pending.pop_front();
      }
      if (is_tf) continue;
      const sensor_msgs::LaserScan::ConstPtr msg = message.instantiate<sensor_msgs::LaserScan>();
      if (!msg) {
        throw SourceError("topic " + options_.scan_topic + " in bag " + options_.bag_path + " holds " +
                          message.getDataType() + ", not " + kLaserScanType);
      }
      const double stamp_s = msg->header.stamp.toSec();
      if (stamp_s < start_s || stamp_s > end_s) {
        ++stats.scans_outside_time_range;
        continue;
      }
      ++stats.scans_read;
      if (!first_bag_time_s) first_bag_time_s = bag_time_s;
      last_bag_time_s = bag_time_s;
      if (impl_->has_tf_messages) {
        pending.push_back(PendingScan{msg, bag_time_s});
      } else {
        deliver(*msg);
      }
    }
    for (const PendingScan& scan : pending) deliver(*scan.msg);
  } catch (const CallbackFailed& failed) {
    std::rethrow_exception(failed.error);
  } catch (const SourceError&) {
    throw;
  } catch (const std::exception& e) {
    // rosbag's errors, and deserialisation overruns, of a bag damaged after its index.
    throw std::runtime_error("bag " + options_.bag_path + " is corrupt: " + e.what());
  }
  stats.bag_duration_s = first_bag_time_s ? *last_bag_time_s - *first_bag_time_s : 0.0;
  report(1.0);
  return stats;
}

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
