#include "dynamic_occupancy_grid/ros/grid_messages.h"

#include <algorithm>
#include <utility>

namespace dynamic_occupancy_grid {
namespace ros_layer {

std::vector<std::int8_t> layerValues(const core::CellGrid& grid, const LayerView& view, std::int64_t step,
                                     const core::CellBox& box) {
  // One pass to int8, rows over the cores; the same values as evaluateLayer followed by
  // toOccupancyValues / toThresholdedOccupancyValues (core/layers/layers.h).
  std::vector<std::int8_t> occupancy;
  core::layerOccupancy(grid, view.layer, step, view.horizon_steps, box,
                       core::OccupancyScaling{view.full_scale, view.thresholds}, &occupancy);
  return occupancy;
}

nav_msgs::OccupancyGrid toOccupancyGrid(const core::MapWindow& window, std::vector<std::int8_t> values,
                                        const std::string& frame_id, const ros::Time& stamp) {
  nav_msgs::OccupancyGrid msg;
  msg.header.frame_id = frame_id;
  msg.header.stamp = stamp;
  msg.info.map_load_time = stamp;
  msg.info.resolution = static_cast<float>(window.resolution_m);
  msg.info.width = static_cast<std::uint32_t>(window.cells.width());
  msg.info.height = static_cast<std::uint32_t>(window.cells.height());
  msg.info.origin.position.x = window.origin_x_m;
  msg.info.origin.position.y = window.origin_y_m;
  msg.info.origin.orientation.w = 1.0;
  msg.data = std::move(values);
  return msg;
}

map_msgs::OccupancyGridUpdate toOccupancyGridUpdate(const core::CellBox& full, const core::CellBox& box,
                                                    std::vector<std::int8_t> values,
                                                    const std::string& frame_id, const ros::Time& stamp) {
  map_msgs::OccupancyGridUpdate msg;
  msg.header.frame_id = frame_id;
  msg.header.stamp = stamp;
  // Offsets are in cells from the full grid's first cell.
  msg.x = static_cast<std::int32_t>(std::int64_t{box.min_x} - full.min_x);
  msg.y = static_cast<std::int32_t>(std::int64_t{box.min_y} - full.min_y);
  msg.width = static_cast<std::uint32_t>(box.width());
  msg.height = static_cast<std::uint32_t>(box.height());
  msg.data = std::move(values);
  return msg;
}

MapHypotheses toMapHypotheses(const core::MemoryModel& memory, std::size_t max_hypotheses,
                              const std::string& frame_id, const ros::Time& stamp) {
  MapHypotheses msg;
  msg.header.frame_id = frame_id;
  msg.header.stamp = stamp;
  msg.updates = static_cast<std::uint32_t>(memory.updates());
  const core::CellBox bounds = memory.bounds();
  const core::MapWindow window = memory.window(bounds);
  const std::vector<core::MapHypothesis> hypotheses = memory.hypotheses();
  msg.total_hypotheses = static_cast<std::uint32_t>(hypotheses.size());
  const std::size_t count = std::min(hypotheses.size(), max_hypotheses);
  msg.hypotheses.reserve(count);
  for (std::size_t i = 0; i < count; ++i) {
    dynamic_occupancy_grid::MapHypothesis hypothesis;
    hypothesis.map = toOccupancyGrid(window, memory.hypothesisGrid(hypotheses[i], bounds), frame_id, stamp);
    hypothesis.weight = hypotheses[i].weight;
    hypothesis.configurations = hypotheses[i].configurations;
    hypothesis.excluded = hypotheses[i].excluded;
    msg.hypotheses.push_back(std::move(hypothesis));
  }
  for (const core::ConfigurationInfo& configuration : memory.configurations()) {
    msg.configuration_ids.push_back(configuration.id);
    msg.configuration_presence.push_back(configuration.presence);
    msg.configuration_cells.push_back(static_cast<std::uint32_t>(configuration.cells));
    msg.configuration_created_update.push_back(static_cast<std::uint32_t>(configuration.created_update));
  }
  return msg;
}

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
