#include "toro_ros/offline/scoring.h"

#include <algorithm>
#include <vector>

#include <Eigen/SVD>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/pipeline/persistence.h"

namespace toro_ros {
namespace offline {

TruthTrajectory TruthTrajectory::load(const std::string& truth_path) {
  const std::string suffix = ".truth.g2o";
  if (truth_path.size() <= suffix.size() ||
      truth_path.compare(truth_path.size() - suffix.size(), suffix.size(), suffix))
    throw std::runtime_error(truth_path +
                             ": a truth file is named <stem>.truth.g2o (as graph_to_bag writes it)");
  const std::string stem = truth_path.substr(0, truth_path.size() - suffix.size());
  const toro::PoseGraph truth = toro::readGraph(truth_path);
  const Sidecar sidecar = readSidecar(sidecarPath(stem + ".odometry.g2o"));
  TruthTrajectory out;
  for (const KeyframeRecord& k : sidecar.keyframes) {
    if (!truth.hasNode(k.id))
      throw std::runtime_error(truth_path + ": no node " + std::to_string(k.id) +
                               " (named in the stamps sidecar)");
    if (!out.stamps_.empty() && k.stamp <= out.stamps_.back())
      throw std::runtime_error(sidecarPath(stem + ".odometry.g2o") + ": stamps do not increase at node " +
                               std::to_string(k.id));
    out.stamps_.push_back(k.stamp);
    out.poses_.push_back(truth.pose(k.id));
  }
  if (out.stamps_.empty()) throw std::runtime_error(truth_path + ": the stamps sidecar lists no node");
  return out;
}

bool TruthTrajectory::at(const ros::Time& stamp, toro::Pose3* pose) const {
  if (stamp < stamps_.front() || stamp > stamps_.back()) return false;
  const auto it = std::lower_bound(stamps_.begin(), stamps_.end(), stamp);
  const std::size_t i = static_cast<std::size_t>(it - stamps_.begin());
  if (*it == stamp) {
    *pose = poses_[i];
    return true;
  }
  const double f = (stamp - stamps_[i - 1]).toSec() / (stamps_[i] - stamps_[i - 1]).toSec();
  *pose = toro::slerp(poses_[i - 1], poses_[i], f);
  return true;
}

namespace {

// RMSE of `a` against `b` after the rotation and translation that best map a onto b (Kabsch).
double alignedRmse(const std::vector<toro::Vector3>& a, const std::vector<toro::Vector3>& b) {
  if (a.empty()) return 0.0;
  toro::Vector3 ca = toro::Vector3::Zero(), cb = toro::Vector3::Zero();
  for (std::size_t i = 0; i < a.size(); ++i) ca += a[i], cb += b[i];
  ca /= static_cast<double>(a.size());
  cb /= static_cast<double>(b.size());
  toro::Matrix3 h = toro::Matrix3::Zero();
  for (std::size_t i = 0; i < a.size(); ++i) h += (a[i] - ca) * (b[i] - cb).transpose();
  const Eigen::JacobiSVD<toro::Matrix3> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
  toro::Matrix3 d = toro::Matrix3::Identity();
  d(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1.0 : 1.0;
  const toro::Matrix3 r = svd.matrixV() * d * svd.matrixU().transpose();
  double sum2 = 0.0;
  for (std::size_t i = 0; i < a.size(); ++i) sum2 += (r * (a[i] - ca) + cb - b[i]).squaredNorm();
  return std::sqrt(sum2 / static_cast<double>(a.size()));
}

}  // namespace

TrajectoryError trajectoryError(const std::vector<ros::Time>& stamps, const std::vector<toro::Pose3>& poses,
                                const TruthTrajectory& truth) {
  TrajectoryError e;
  double sum2 = 0.0, sum = 0.0, rotation = 0.0;
  std::vector<toro::Vector3> estimated, reference;
  for (std::size_t i = 0; i < stamps.size(); ++i) {
    toro::Pose3 t;
    if (!truth.at(stamps[i], &t)) continue;
    estimated.push_back(poses[i].translation());
    reference.push_back(t.translation());
    const double d = (poses[i].translation() - t.translation()).norm();
    sum2 += d * d;
    sum += d;
    e.max_m = std::max(e.max_m, d);
    rotation += toro::relativePose(t, poses[i]).angle();
    e.final_m = d;
    ++e.poses;
  }
  if (e.poses == 0) return e;
  e.rmse_m = std::sqrt(sum2 / e.poses);
  e.mean_m = sum / e.poses;
  e.mean_rotation_rad = rotation / e.poses;
  e.rmse_aligned_m = alignedRmse(estimated, reference);
  return e;
}

Score scoreKeyframes(const std::vector<KeyframeRecord>& keyframes, const std::vector<toro::Pose3>& corrected,
                     const TruthTrajectory& truth) {
  if (keyframes.size() != corrected.size())
    throw std::invalid_argument("scoreKeyframes: " + std::to_string(keyframes.size()) + " keyframes but " +
                                std::to_string(corrected.size()) + " corrected poses");
  std::vector<ros::Time> stamps;
  std::vector<toro::Pose3> odometry;
  for (const KeyframeRecord& k : keyframes) {
    stamps.push_back(k.stamp);
    odometry.push_back(k.odom_T_base);
  }
  return Score{trajectoryError(stamps, odometry, truth), trajectoryError(stamps, corrected, truth)};
}

std::string describeScore(const Score& s) {
  std::ostringstream out;
  out.precision(4);
  auto line = [&out](const char* what, const TrajectoryError& e) {
    out << what << ": position RMSE " << e.rmse_m << " m, mean " << e.mean_m << " m, max " << e.max_m
        << " m, final " << e.final_m << " m, mean rotation " << e.mean_rotation_rad * 180.0 / M_PI << " deg ("
        << e.poses << " keyframes); " << e.rmse_aligned_m << " m after the best rigid alignment\n";
  };
  line("error vs truth before (odometry)", s.odometry);
  line("error vs truth after (corrected)", s.corrected);
  return out.str();
}

}  // namespace offline
}  // namespace toro_ros
