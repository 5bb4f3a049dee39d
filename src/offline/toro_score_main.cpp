// toro_score: a saved corrected graph (+ its .stamps sidecar) against graph_to_bag's truth.
#include "toro_ros/offline/apps.h"

int main(int argc, char** argv) { return toro_ros::offline::runToroScore(argc, argv); }
