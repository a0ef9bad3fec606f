// The mapping node as a nodelet (dynamic_occupancy_grid/MappingNodelet): same class, same
// topics, services and parameters as mapping_node. Scans, tf and the timers run on the
// nodelet's own (single-threaded) queue; the services on MappingNode's queue with threads of
// its own, so that a stuck request delays neither this nodelet's scans nor, by holding one of
// the manager's worker threads, other nodelets.
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>

#include <memory>

#include "dynamic_occupancy_grid/ros/mapping_node.h"

namespace dynamic_occupancy_grid {
namespace ros_layer {

class MappingNodelet : public nodelet::Nodelet {
 private:
  void onInit() override {
    node_ = std::make_unique<MappingNode>(getNodeHandle(), getPrivateNodeHandle());
    if (!node_->start()) {
      NODELET_FATAL("bad parameters (see above); the nodelet does nothing");
      node_.reset();
    }
  }

  std::unique_ptr<MappingNode> node_;
};

}  // namespace ros_layer
}  // namespace dynamic_occupancy_grid

PLUGINLIB_EXPORT_CLASS(dynamic_occupancy_grid::ros_layer::MappingNodelet, nodelet::Nodelet)
