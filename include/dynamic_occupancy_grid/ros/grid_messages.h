#pragma once
// Map layers as nav_msgs/OccupancyGrid and map_msgs/OccupancyGridUpdate: the one place that
// turns core layer values into messages.

#include <map_msgs/OccupancyGridUpdate.h>
#include <nav_msgs/OccupancyGrid.h>
#include <ros/time.h>

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "dynamic_occupancy_grid/core/grid/cell_grid.h"
#include "dynamic_occupancy_grid/core/layers/layers.h"
#include "dynamic_occupancy_grid/core/memory/memory_model.h"
#include "dynamic_occupancy_grid/MapHypotheses.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {

/// How one published layer is evaluated and scaled.
struct LayerView {
  core::Layer layer = core::Layer::kBelief;
  float full_scale = 1.0f;            ///< value shown as 100 (probabilities: 1)
  std::int64_t horizon_steps = 0;     ///< kPredicted only
  /// Probability layers for map consumers (the `map` topic): map_server's thresholds
  /// instead of the plain 0..100 scaling; full_scale is then unused.
  std::optional<core::OccupancyThresholds> thresholds;
};

/// `view` over `box` at `step` as 0..100 / -1 values (row-major, OccupancyGrid order), by
/// core::layerOccupancy (one pass, rows over the cores; values identical to evaluateLayer +
/// toOccupancyValues / toThresholdedOccupancyValues).
std::vector<std::int8_t> layerValues(const core::CellGrid& grid, const LayerView& view, std::int64_t step,
                                     const core::CellBox& box);

/// A full grid over `window` (an empty window gives a 0 x 0 grid).
nav_msgs::OccupancyGrid toOccupancyGrid(const core::MapWindow& window, std::vector<std::int8_t> values,
                                        const std::string& frame_id, const ros::Time& stamp);

/// An update of `box`, which lies inside `full` (the window of the last full grid sent).
map_msgs::OccupancyGridUpdate toOccupancyGridUpdate(const core::CellBox& full, const core::CellBox& box,
                                                    std::vector<std::int8_t> values,
                                                    const std::string& frame_id, const ros::Time& stamp);

/// The memory model's hypotheses: the best `max_hypotheses` (by weight), each with its map
/// as a full grid over the model's bounds, and every configuration in LTM.
MapHypotheses toMapHypotheses(const core::MemoryModel& memory, std::size_t max_hypotheses,
                              const std::string& frame_id, const ros::Time& stamp);

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
