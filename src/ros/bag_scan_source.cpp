#include "dynamic_occupancy_grid/ros/bag_scan_source.h"

#include <rosbag/bag.h>
#include <rosbag/exceptions.h>
#include <rosbag/view.h>
#include <sensor_msgs/LaserScan.h>
#include <tf2/buffer_core.h>
#include <tf2/exceptions.h>
#include <tf2_msgs/TFMessage.h>

#include <stdexcept>
#include <utility>

#include "dynamic_occupancy_grid/ros/conversions.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {
namespace {

std::string withLeadingSlash(const std::string& topic) {
  return (!topic.empty() && topic.front() == '/') ? topic : "/" + topic;
}

std::string withoutLeadingSlash(const std::string& frame) {
  return (!frame.empty() && frame.front() == '/') ? frame.substr(1) : frame;
}

}  // namespace

struct BagScanSource::Impl {
  rosbag::Bag bag;
  std::unique_ptr<tf2::BufferCore> tf;
  double duration_s = 0.0;
};

BagScanSource::BagScanSource(BagScanSourceOptions options)
    : options_(std::move(options)), impl_(std::make_unique<Impl>()) {
  options_.scan_topic = withLeadingSlash(options_.scan_topic);
  options_.fixed_frame = withoutLeadingSlash(options_.fixed_frame);
  try {
    impl_->bag.open(options_.bag_path, rosbag::bagmode::Read);
    rosbag::View scans(impl_->bag, rosbag::TopicQuery(options_.scan_topic));
    if (scans.size() == 0) {
      throw std::runtime_error("bag " + options_.bag_path + " has no messages on topic " +
                               options_.scan_topic);
    }
    impl_->duration_s = (scans.getEndTime() - scans.getBeginTime()).toSec();
    if (options_.static_laser_pose) return;
    // The whole bag's transforms in one buffer: a scan may be older than the transforms
    // recorded just after it, and bags are read in one go, not in real time.
    rosbag::View tf_view(impl_->bag, rosbag::TopicQuery(std::vector<std::string>{"/tf", "/tf_static"}));
    const double cache_s = (tf_view.size() > 0 ? (tf_view.getEndTime() - tf_view.getBeginTime()).toSec() : 0.0) + 60.0;
    impl_->tf = std::make_unique<tf2::BufferCore>(ros::Duration(cache_s));
    for (const rosbag::MessageInstance& message : tf_view) {
      const tf2_msgs::TFMessage::ConstPtr transforms = message.instantiate<tf2_msgs::TFMessage>();
      if (!transforms) continue;
      const bool is_static = message.getTopic() == "/tf_static";
      for (const geometry_msgs::TransformStamped& transform : transforms->transforms) {
        impl_->tf->setTransform(transform, "bag", is_static);
      }
    }
  } catch (const rosbag::BagException& e) {
    throw std::runtime_error("cannot read bag " + options_.bag_path + ": " + e.what());
  }
}

BagScanSource::~BagScanSource() = default;

BagScanStats BagScanSource::forEachScan(const std::function<void(const core::Scan&)>& on_scan,
                                        const std::function<void(double)>& on_progress) {
  BagScanStats stats;
  stats.bag_duration_s = impl_->duration_s;
  try {
    rosbag::View scans(impl_->bag, rosbag::TopicQuery(options_.scan_topic));
    const double begin_s = scans.getBeginTime().toSec();
    std::size_t count = 0;
    for (const rosbag::MessageInstance& message : scans) {
      const sensor_msgs::LaserScan::ConstPtr msg = message.instantiate<sensor_msgs::LaserScan>();
      if (!msg) {
        throw std::runtime_error("topic " + options_.scan_topic + " in " + options_.bag_path +
                                 " holds " + message.getDataType() + ", not sensor_msgs/LaserScan");
      }
      ++stats.scans_read;
      core::Pose2D pose;
      bool upside_down = false;
      if (options_.static_laser_pose) {
        pose = *options_.static_laser_pose;
      } else {
        try {
          const geometry_msgs::TransformStamped transform = impl_->tf->lookupTransform(
              options_.fixed_frame, withoutLeadingSlash(msg->header.frame_id), msg->header.stamp);
          std::string error;
          if (!toLaserPose(transform.transform, &pose, &upside_down, &error)) {
            throw tf2::TransformException(error);
          }
        } catch (const tf2::TransformException& e) {
          ++stats.scans_without_pose;
          stats.last_pose_error = e.what();
          continue;
        }
      }
      on_scan(toCoreScan(*msg, pose, upside_down));
      if (on_progress && (++count % 64 == 0) && impl_->duration_s > 0.0) {
        on_progress((message.getTime().toSec() - begin_s) / impl_->duration_s);
      }
    }
  } catch (const rosbag::BagException& e) {
    throw std::runtime_error("bag " + options_.bag_path + " is corrupt: " + e.what());
  }
  if (on_progress) on_progress(1.0);
  return stats;
}

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
