// mapping_node: the dynamic occupancy grid mapping node. See README.md, "mapping_node".
#include <ros/ros.h>

#include "dynamic_occupancy_grid/ros/mapping_node.h"

int main(int argc, char** argv) {
  ros::init(argc, argv, "dynamic_occupancy_grid");
  dynamic_occupancy_grid::ros_layer::MappingNode node{ros::NodeHandle(), ros::NodeHandle("~")};
  if (!node.start()) return 1;
  ros::spin();
  return 0;
}
