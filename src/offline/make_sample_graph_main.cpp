// make_sample_graph: the bundled sample's synthetic graph (see sample_graph.h).
#include "toro_ros/offline/apps.h"

int main(int argc, char** argv) { return toro_ros::offline::runMakeSampleGraph(argc, argv); }
