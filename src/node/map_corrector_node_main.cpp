// map_corrector_node: online pose-graph map correction (see MapCorrectorNode).
#include <exception>

#include <ros/ros.h>

#include "toro_ros/node/map_corrector_node.h"

int main(int argc, char** argv) {
  ros::init(argc, argv, "map_corrector");
  try {
    toro_ros::MapCorrectorNode node(ros::NodeHandle(), ros::NodeHandle("~"));
    ros::spin();
  } catch (const std::exception& e) {
    ROS_FATAL_STREAM("map corrector: " << e.what());
    return 1;
  }
  return 0;
}
