// The offline command-line tools as functions (argument parsing, the work, messages, exit code);
// their main()s only call these.  Exit codes: 0 success, 1 failure (message on stderr), 2 usage.
#pragma once

namespace toro_ros {
namespace offline {

int runGraphToBag(int argc, char** argv);
int runToroOffline(int argc, char** argv);
int runToroScore(int argc, char** argv);
int runMakeSampleGraph(int argc, char** argv);
int runMakePlanarRobot(int argc, char** argv);

}  // namespace offline
}  // namespace toro_ros
