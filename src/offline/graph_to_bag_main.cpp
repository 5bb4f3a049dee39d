// graph_to_bag: a pose-graph file as a robot's bag (see include/toro_ros/offline/graph_to_bag.h).
#include "toro_ros/offline/apps.h"

int main(int argc, char** argv) { return toro_ros::offline::runGraphToBag(argc, argv); }
