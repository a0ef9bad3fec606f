#pragma once
// A laser scan as the core sees it: no ROS types, the laser's 2D pose in the map frame
// already resolved (the ROS layer looks it up in tf at the scan stamp).

#include <vector>

namespace dynamic_occupancy_grid {
namespace core {

/// Position (m) and heading (rad, counter-clockwise from the x axis) in the map frame.
struct Pose2D {
  double x_m = 0.0;
  double y_m = 0.0;
  double yaw_rad = 0.0;
};

/// The fields of sensor_msgs/LaserScan the mapper uses. Beam i points at
/// laser_pose.yaw_rad + s * (angle_min_rad + i * angle_increment_rad), s = -1 for a laser
/// mounted upside down (its angles turn clockwise seen from above), +1 otherwise.
struct Scan {
  double stamp_s = 0.0;  ///< sensor time, seconds
  Pose2D laser_pose;
  bool upside_down = false;
  double angle_min_rad = 0.0;
  double angle_increment_rad = 0.0;
  double range_min_m = 0.0;
  double range_max_m = 0.0;
  std::vector<float> ranges_m;
};

}  // namespace core
}  // namespace dynamic_occupancy_grid
