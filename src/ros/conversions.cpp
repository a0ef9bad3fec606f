#include "dynamic_occupancy_grid/ros/conversions.h"

#include <cmath>
#include <string>

namespace dynamic_occupancy_grid {
namespace ros_layer {

bool toLaserPose(const geometry_msgs::Transform& fixed_from_laser, core::Pose2D* pose,
                 bool* upside_down, std::string* error) {
  const double w = fixed_from_laser.rotation.w;
  const double x = fixed_from_laser.rotation.x;
  const double y = fixed_from_laser.rotation.y;
  const double z = fixed_from_laser.rotation.z;
  const double norm = std::sqrt(w * w + x * x + y * y + z * z);
  if (!(norm > 0.0) || !std::isfinite(norm)) {
    *error = "transform has an invalid rotation quaternion";
    return false;
  }
  // Columns of the rotation matrix: the laser's x axis and z axis in the fixed frame.
  const double s = 2.0 / (norm * norm);
  const double x_axis_x = 1.0 - s * (y * y + z * z);
  const double x_axis_y = s * (x * y + w * z);
  const double z_axis_z = 1.0 - s * (x * x + y * y);
  if (std::abs(z_axis_z) < std::cos(25.0 * M_PI / 180.0)) {
    *error = "laser plane is tilted more than 25 degrees from the fixed frame's xy plane";
    return false;
  }
  pose->x_m = fixed_from_laser.translation.x;
  pose->y_m = fixed_from_laser.translation.y;
  pose->yaw_rad = std::atan2(x_axis_y, x_axis_x);
  *upside_down = z_axis_z < 0.0;
  return true;
}

geometry_msgs::Transform toTransform(const core::Pose2D& pose) {
  geometry_msgs::Transform transform;
  transform.translation.x = pose.x_m;
  transform.translation.y = pose.y_m;
  transform.rotation.z = std::sin(pose.yaw_rad / 2.0);
  transform.rotation.w = std::cos(pose.yaw_rad / 2.0);
  return transform;
}

bool checkScanShape(const sensor_msgs::LaserScan& msg, std::string* error) {
  if (msg.ranges.size() < 2) return true;
  const double span = static_cast<double>(msg.angle_max) - msg.angle_min;
  if (!std::isfinite(span) || !std::isfinite(msg.angle_increment) || msg.angle_increment == 0.0f) {
    return true;  // the core rejects these with its own message
  }
  const double beams = span / msg.angle_increment + 1.0;
  if (!(std::abs(beams - static_cast<double>(msg.ranges.size())) <= 1.5)) {
    *error = "scan has " + std::to_string(msg.ranges.size()) + " ranges, but angle_min " +
             std::to_string(msg.angle_min) + ", angle_max " + std::to_string(msg.angle_max) +
             " and angle_increment " + std::to_string(msg.angle_increment) + " make " +
             std::to_string(static_cast<long long>(std::lround(beams))) + " beams";
    return false;
  }
  return true;
}

core::Scan toCoreScan(const sensor_msgs::LaserScan& msg, const core::Pose2D& pose, bool upside_down) {
  core::Scan scan;
  scan.stamp_s = msg.header.stamp.toSec();
  scan.laser_pose = pose;
  scan.upside_down = upside_down;
  scan.angle_min_rad = msg.angle_min;
  scan.angle_increment_rad = msg.angle_increment;
  scan.range_min_m = msg.range_min;
  scan.range_max_m = msg.range_max;
  scan.ranges_m = msg.ranges;
  return scan;
}

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
