// map_corrector as a nodelet: the same MapCorrectorNode as the plain node, on the manager's
// node handles (its subscriptions and wall timers then run on the manager's callback queue; the
// node's own queues for tf and services are unchanged).  Load it into a manager with
//   rosrun nodelet nodelet load toro_ros/MapCorrectorNodelet MANAGER
// or launch/map_corrector.launch manager:=MANAGER.
#include <memory>

#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>

#include "toro_ros/node/map_corrector_node.h"

namespace toro_ros {

class MapCorrectorNodelet : public nodelet::Nodelet {
 public:
  // The node's destructor stops its threads and autosaves, as the plain node does on exit.
  ~MapCorrectorNodelet() override = default;

 private:
  void onInit() override {
    try {
      node_ = std::make_unique<MapCorrectorNode>(getNodeHandle(), getPrivateNodeHandle());
    } catch (const std::exception& e) {
      // The manager keeps running; the nodelet stays unloaded in effect, and says why.
      NODELET_FATAL_STREAM("map corrector: " << e.what());
    }
  }

  std::unique_ptr<MapCorrectorNode> node_;
};

}  // namespace toro_ros

PLUGINLIB_EXPORT_CLASS(toro_ros::MapCorrectorNodelet, nodelet::Nodelet)
