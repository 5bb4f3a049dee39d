// map_corrector_node: online pose-graph map correction (see MapCorrectorNode).
#include <csignal>
#include <exception>

#include <ros/ros.h>

#include "toro_ros/core/blas_kernels.h"
#include "toro_ros/node/map_corrector_node.h"

namespace {

// roscpp handles SIGINT (Ctrl-C, roslaunch); SIGTERM (systemd, docker stop, kill) should end the
// node as cleanly, so the graph is autosaved on the way out.  ros::requestShutdown only sets a
// flag, which is what roscpp's own SIGINT handler does.
void requestShutdown(int) { ros::requestShutdown(); }

}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "map_corrector");
  std::signal(SIGTERM, requestShutdown);
  // The process is the node's and no thread of it is in the BLAS yet: OpenBLAS's kernels may be
  // switched here (the node reports the result).
  toro::selectBlasKernels(/*may_switch=*/true);
  try {
    toro_ros::MapCorrectorNode node(ros::NodeHandle(), ros::NodeHandle("~"));
    ros::spin();
  } catch (const std::exception& e) {
    ROS_FATAL_STREAM("map corrector: " << e.what());
    return 1;
  }
  return 0;
}
