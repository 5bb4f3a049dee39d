#include <iostream>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/offline/apps.h"
#include "toro_ros/offline/cli.h"
#include "toro_ros/offline/scoring.h"
#include "toro_ros/pipeline/persistence.h"

namespace toro_ros {
namespace offline {

namespace {

// Prints chi2 at the odometry poses (from the sidecar) and at the corrected poses, and the score.
void score(const std::string& corrected_path, const std::string& truth_path) {
  const toro::PoseGraph corrected = toro::readGraph(corrected_path);
  const Sidecar sidecar = readSidecar(sidecarPath(corrected_path));
  if (sidecar.keyframes.size() != corrected.numNodes())
    throw std::runtime_error(sidecarPath(corrected_path) + ": " + std::to_string(sidecar.keyframes.size()) +
                             " keyframes but the graph has " + std::to_string(corrected.numNodes()) +
                             " nodes");
  toro::PoseGraph odometry = corrected;
  std::vector<toro::Pose3> poses;
  for (std::size_t i = 0; i < sidecar.keyframes.size(); ++i) {
    const KeyframeRecord& k = sidecar.keyframes[i];
    poses.push_back(corrected.pose(k.id));
    odometry.setPose(k.id, k.odom_T_base);
  }
  std::cout << corrected.numNodes() << " keyframes, " << corrected.numConstraints() << " constraints ("
            << sidecar.loop_closures.size() << " loop closures)\n"
            << "chi2 before (odometry) " << toro::g2oChi2(odometry) << ", after " << toro::g2oChi2(corrected)
            << "\n";
  if (!truth_path.empty())
    std::cout << describeScore(scoreKeyframes(sidecar.keyframes, poses, TruthTrajectory::load(truth_path)));
}

}  // namespace

int runToroScore(int argc, char** argv) {
  const std::vector<ArgSpec> specs;
  try {
    const ParsedArgs args = parseArgs(argc, argv, specs);
    if (args.help || args.positional.empty() || args.positional.size() > 2) {
      std::cerr << usage("toro_score CORRECTED.g2o [TRUTH.truth.g2o]  (CORRECTED.g2o.stamps must exist)",
                         specs);
      return args.help ? 0 : 2;
    }
    score(args.positional[0], args.positional.size() > 1 ? args.positional[1] : "");
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "toro_score: " << e.what() << "\n";
    return 1;
  }
}

}  // namespace offline
}  // namespace toro_ros
