// make_planar_robot: the planar test robot's bag and truth (see planar_robot.h).
#include "toro_ros/offline/apps.h"

int main(int argc, char** argv) { return toro_ros::offline::runMakePlanarRobot(argc, argv); }
