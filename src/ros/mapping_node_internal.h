#pragma once
// Private to the mapping node's sources (src/ros/mapping_node*.cpp): the constants and
// helpers more than one of them uses.

#include <ros/time.h>

#include <cmath>
#include <cstdint>

#include "dynamic_occupancy_grid/core/grid/mapper.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {
namespace mapping_node_internal {

/// Stamps this close to ROS time are on its clock (a scan's way to the node, one arriving
/// before /clock moved on); further off, the scans run on another clock.
inline constexpr double kStampOffsetToleranceS = 1.0;

// Map stamps are sensor times; ros::Time cannot hold negative ones.
inline ros::Time toRosTime(double stamp_s) {
  return stamp_s > 0.0 && stamp_s < 4.0e9 ? ros::Time(stamp_s) : ros::Time(0, 0);
}

// Same lattice: the cells of one map are the cells of the other.
inline bool sameLattice(const core::MapperConfig& a, const core::MapperConfig& b) {
  return a.resolution_m == b.resolution_m && a.origin_x_m == b.origin_x_m && a.origin_y_m == b.origin_y_m &&
         a.time_step_s == b.time_step_s;
}

inline std::int64_t horizonSteps(double horizon_s, double time_step_s) {
  return static_cast<std::int64_t>(std::llround(horizon_s / time_step_s));
}

// A loaded model takes this node's settings for what model files leave out: how a step's
// beams are read and how readings change with the view.
inline void applySettingsModelFilesLeaveOut(core::Mapper& mapper, const core::MapperConfig& config) {
  mapper.setViewSwitchProbability(config.kinds.view_switch_probability);
  mapper.setMixedStepProbability(config.sensor_model_mixed_step_probability);
}

}  // namespace mapping_node_internal
}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
