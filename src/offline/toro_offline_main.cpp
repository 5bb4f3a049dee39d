// toro_offline: a bag through the node's pipeline at full speed (see offline_runner.h).
#include "toro_ros/offline/apps.h"

int main(int argc, char** argv) { return toro_ros::offline::runToroOffline(argc, argv); }
