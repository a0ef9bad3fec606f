#pragma once
// The mapping node: LaserScans (through tf2_ros::MessageFilter on the fixed frame) into a
// core::Mapper, the map layers out as latched OccupancyGrids plus their updates, and the
// services. One class for the node (src/nodes/mapping_node.cpp) and the nodelet
// (src/ros/mapping_nodelet.cpp). Topics, services and parameters: README.md.

#include <message_filters/subscriber.h>
#include <ros/ros.h>
#include <sensor_msgs/LaserScan.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/message_filter.h>
#include <tf2_ros/transform_listener.h>

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "dynamic_occupancy_grid/ExportLayers.h"
#include "dynamic_occupancy_grid/GetCell.h"
#include "dynamic_occupancy_grid/LoadModel.h"
#include "dynamic_occupancy_grid/PredictMap.h"
#include "dynamic_occupancy_grid/RunOfflineEm.h"
#include "dynamic_occupancy_grid/SaveModel.h"
#include "dynamic_occupancy_grid/core/mapper.h"
#include "dynamic_occupancy_grid/ros/grid_messages.h"
#include "dynamic_occupancy_grid/ros/parameters.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {

class MappingNode {
 public:
  /// `nh` for the `map` topic (publish_map_topic), `private_nh` for everything else.
  MappingNode(const ros::NodeHandle& nh, const ros::NodeHandle& private_nh);
  /// Stops a running offline EM and waits for it.
  ~MappingNode();
  MappingNode(const MappingNode&) = delete;
  MappingNode& operator=(const MappingNode&) = delete;

  /// Reads and checks the parameters (a bad one: logged with its name, returns false,
  /// nothing advertised), loads ~model_file if set, then subscribes and advertises.
  bool start();

 private:
  /// One published layer: the full grid and its updates.
  struct Output {
    LayerView view;
    ros::Publisher full;
    ros::Publisher updates;
    bool needs_full = true;        ///< a new subscriber, new bounds or a new model
    bool horizon_from_parameter = false;
  };

  void scanCallback(const sensor_msgs::LaserScan::ConstPtr& msg);
  void scanDropped(const sensor_msgs::LaserScan::ConstPtr& msg, tf2_ros::FilterFailureReason reason);
  void publishTimer(const ros::TimerEvent& event);
  void publishLayers(bool force_full);
  /// The full grid of `output` now; caller holds mutex_.
  void publishFull(Output& output);
  /// Puts `mapper` in place of the live one (load, reset); caller holds mutex_.
  void replaceMapper(std::unique_ptr<core::Mapper> mapper);

  bool runOfflineEm(RunOfflineEm::Request& request, RunOfflineEm::Response& response);
  bool saveModel(SaveModel::Request& request, SaveModel::Response& response);
  bool loadModel(LoadModel::Request& request, LoadModel::Response& response);
  bool exportLayers(ExportLayers::Request& request, ExportLayers::Response& response);
  bool reset(std_srvs::Trigger::Request& request, std_srvs::Trigger::Response& response);
  bool getCell(GetCell::Request& request, GetCell::Response& response);
  bool predictMap(PredictMap::Request& request, PredictMap::Response& response);

  ros::NodeHandle nh_;
  ros::NodeHandle private_nh_;
  NodeParameters parameters_;

  tf2_ros::Buffer tf_buffer_;
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;
  std::vector<std::unique_ptr<message_filters::Subscriber<sensor_msgs::LaserScan>>> scan_subscribers_;
  std::vector<std::unique_ptr<tf2_ros::MessageFilter<sensor_msgs::LaserScan>>> scan_filters_;

  std::vector<Output> outputs_;
  ros::Publisher offline_em_progress_;
  std::vector<ros::ServiceServer> services_;
  ros::Timer publish_timer_;

  /// Guards everything below (scans, services, the timer and the offline EM thread).
  std::mutex mutex_;
  std::unique_ptr<core::Mapper> mapper_;
  std::optional<double> newest_stamp_s_;  ///< newest scan stamp integrated
  core::CellBox published_bounds_;        ///< bounds of the last full grids
  ros::Time last_full_publish_;

  std::thread offline_em_thread_;
  std::atomic<bool> offline_em_running_{false};
  std::atomic<bool> offline_em_cancel_{false};
};

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid
