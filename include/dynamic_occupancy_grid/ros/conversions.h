#pragma once
// The one place that converts between ROS messages and core types.

#include <geometry_msgs/Transform.h>
#include <sensor_msgs/LaserScan.h>

#include <string>

#include "dynamic_occupancy_grid/core/grid/scan.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {

/// The laser's 2D pose from the transform fixed_frame <- laser_frame. Sets `upside_down`
/// when the laser's z axis points down. Returns false (and says why in `error`) when the
/// laser plane is tilted more than ~25 degrees from horizontal: a 2D map cannot use it.
bool toLaserPose(const geometry_msgs::Transform& fixed_from_laser, core::Pose2D* pose,
                 bool* upside_down, std::string* error);

/// A 2D pose as a transform: a rotation about z by its yaw, z = 0.
geometry_msgs::Transform toTransform(const core::Pose2D& pose);

/// Checks what the core cannot see: the number of ranges against angle_min/angle_max/
/// angle_increment (one off is tolerated: drivers round differently). The core checks the
/// rest (empty scan, range_min/range_max, non-finite angles). Returns false with a reason.
bool checkScanShape(const sensor_msgs::LaserScan& msg, std::string* error);

/// A LaserScan seen from `pose` as a core::Scan.
core::Scan toCoreScan(const sensor_msgs::LaserScan& msg, const core::Pose2D& pose, bool upside_down);

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
