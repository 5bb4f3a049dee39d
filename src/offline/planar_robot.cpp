#include "toro_ros/offline/planar_robot.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>

#include <rosbag/bag.h>
#include <rosbag/exceptions.h>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/random_draws.h"
#include "toro_ros/offline/graph_to_bag.h"
#include "toro_ros/offline/robot_messages.h"
#include "toro_ros/pipeline/covariance_conversion.h"
#include "toro_ros/pipeline/msg_conversion.h"
#include "toro_ros/pipeline/persistence.h"

namespace toro_ros {
namespace offline {

namespace {

constexpr double kUnmeasuredVariance = 1e6;  // what diff_drive_controller and 2D matchers publish
constexpr double kTwoDModeVariance = 1e-6;   // robot_localization's two_d_mode z, roll, pitch

bool positive(double v) { return std::isfinite(v) && v > 0; }
bool nonNegative(double v) { return std::isfinite(v) && v >= 0; }

ros::Time stampAt(const PlanarRobotOptions& o, double t) {
  return ros::Time(o.start_sec) + ros::Duration().fromNSec(std::llround(t * 1e9));
}

// The true pose after `s` metres of path, looking along it.
toro::Pose3 pathPose(const RoundedRectangle& path, double s) {
  const toro::Vector3 p = path.pointAt(s), d = path.pointAt(s + 0.01) - path.pointAt(s - 0.01);
  return toro::Pose3::fromRollPitchYaw(p.x(), p.y(), 0.0, 0.0, 0.0, std::atan2(d.y(), d.x()));
}

// x, y, yaw (indices 0, 1, 5 of a 6x6 covariance) of the odometry's state.
struct PlanarState {
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
};

// The EKF prediction for the step (ux, uy, ua) in the body frame from heading `theta`.
void propagate(PlanarState* s, double theta, double ux, double uy, const Eigen::Matrix3d& step_noise) {
  const double c = std::cos(theta), sn = std::sin(theta);
  Eigen::Matrix3d f = Eigen::Matrix3d::Identity();
  f(0, 2) = -sn * ux - c * uy;
  f(1, 2) = c * ux - sn * uy;
  Eigen::Matrix3d g = Eigen::Matrix3d::Identity();
  g.topLeftCorner<2, 2>() << c, -sn, sn, c;
  s->covariance = f * s->covariance * f.transpose() + g * step_noise * g.transpose();
}

Covariance6 odometryCovariance(const PlanarRobotOptions& o, const PlanarState& state) {
  toro::Matrix6 c = toro::Matrix6::Zero();
  const int planar[3] = {0, 1, 5};
  switch (o.covariance_style) {
    case OdometryCovarianceStyle::kConstant:
      c.diagonal() << o.odometry_translation_stddev_m * o.odometry_translation_stddev_m,
          o.odometry_translation_stddev_m * o.odometry_translation_stddev_m, kUnmeasuredVariance,
          kUnmeasuredVariance, kUnmeasuredVariance, o.odometry_yaw_stddev_rad * o.odometry_yaw_stddev_rad;
      break;
    case OdometryCovarianceStyle::kEkfTwoD:
    case OdometryCovarianceStyle::kEkfTwoDZero: {
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) c(planar[i], planar[j]) = state.covariance(i, j);
      const double held = o.covariance_style == OdometryCovarianceStyle::kEkfTwoD ? kTwoDModeVariance : 0.0;
      c(2, 2) = c(3, 3) = c(4, 4) = held;
      break;
    }
    case OdometryCovarianceStyle::kZero:
      break;
  }
  return covarianceToMsg(c);
}

nav_msgs::Odometry odometryMessage(const ros::Time& stamp, const toro::Pose3& odom_T_base,
                                   const Covariance6& covariance, const toro::Pose3& step, double period) {
  nav_msgs::Odometry m;
  m.header.stamp = stamp;
  m.header.frame_id = "odom";
  m.child_frame_id = "base_link";
  m.pose.pose = poseToMsg(odom_T_base);
  m.pose.covariance = covariance;
  m.twist.twist.linear.x = step.translation().x() / period;
  m.twist.twist.linear.y = step.translation().y() / period;
  m.twist.twist.angular.z = step.rollPitchYaw().z() / period;
  return m;
}

void addOdometry(const PlanarRobotOptions& o, std::mt19937& rng, PlanarRobot* robot) {
  const double period = 1.0 / o.odometry_rate_hz;
  const long samples = std::lround(o.laps * o.path.perimeter() / o.speed_mps * o.odometry_rate_hz);
  const toro::Pose3 world_T_start_inverse = pathPose(o.path, 0.0).inverse();
  std::normal_distribution<double> unit(0.0, 1.0);
  toro::Pose3 odom, previous_truth;
  PlanarState state;
  toro::Pose3 reading;
  for (long k = 0; k <= samples; ++k) {
    const toro::Pose3 truth = world_T_start_inverse * pathPose(o.path, o.speed_mps * k * period);
    if (k > 0) {
      const toro::Pose3 step = toro::relativePose(previous_truth, truth);
      const double d = step.translation().norm(), a = step.rollPitchYaw().z();
      const double motion = d + std::abs(a);
      const double st = o.odometry_translation_stddev_m * std::sqrt(motion);
      const double sa = o.odometry_yaw_stddev_rad * std::sqrt(motion);
      const double ux = (1 + o.odometry_scale_error) * step.translation().x() + st * unit(rng);
      const double uy = (1 + o.odometry_scale_error) * step.translation().y() + st * unit(rng);
      const double ua = a + o.odometry_yaw_bias_rad_per_m * d + sa * unit(rng);
      reading = toro::Pose3::fromRollPitchYaw(ux, uy, 0, 0, 0, ua);
      propagate(&state, odom.rollPitchYaw().z(), ux, uy,
                Eigen::Vector3d(st * st, st * st, sa * sa).asDiagonal());
      odom = odom * reading;
    }
    robot->truth.push_back(truth);
    robot->odometry.push_back(
        odometryMessage(stampAt(o, k * period), odom, odometryCovariance(o, state), reading, period));
    previous_truth = truth;
  }
  robot->path_length_m = o.speed_mps * samples * period;
}

LoopClosure scanMatch(const PlanarRobotOptions& o, double t_from, double t_to, std::mt19937& rng) {
  const toro::Pose3 start_inverse = pathPose(o.path, 0.0).inverse();
  const toro::Pose3 from = start_inverse * pathPose(o.path, o.speed_mps * t_from);
  const toro::Pose3 to = start_inverse * pathPose(o.path, o.speed_mps * t_to);
  std::normal_distribution<double> unit(0.0, 1.0);
  const double st = o.loop_closure_translation_stddev_m, sa = o.loop_closure_yaw_stddev_rad;
  const double sz = o.loop_closure_out_of_plane_stddev;
  const auto d = toro::drawLastFirst<6>(unit, rng);
  const toro::Pose3 noise =
      toro::Pose3::fromRollPitchYaw(st * d[0], st * d[1], sz * d[2], sz * d[3], sz * d[4], sa * d[5]);
  LoopClosure msg;
  msg.stamp_from = stampAt(o, t_from);
  msg.stamp_to = stampAt(o, t_to);
  msg.id_from = msg.id_to = -1;
  msg.from_T_to = poseToMsg(toro::relativePose(from, to) * noise);
  toro::Matrix6 c = toro::Matrix6::Zero();
  c.diagonal() << st * st, st * st, kUnmeasuredVariance, kUnmeasuredVariance, kUnmeasuredVariance, sa * sa;
  msg.covariance = covarianceToMsg(c);
  msg.header.stamp = stampAt(o, t_to + o.loop_closure_latency_sec);
  msg.header.frame_id = "odom";
  return msg;
}

void addLoopClosures(const PlanarRobotOptions& o, std::mt19937& rng, PlanarRobot* robot) {
  const double lap = o.path.perimeter(), scan_period = 1.0 / o.scan_rate_hz;
  const double end_sec = (robot->odometry.back().header.stamp - ros::Time(o.start_sec)).toSec();
  auto scanNear = [&](double t) {
    return o.scan_offset_sec + scan_period * std::round((t - o.scan_offset_sec) / scan_period);
  };
  std::uniform_real_distribution<double> offset(-o.loop_closure_offset_m, o.loop_closure_offset_m);
  for (double s = lap + o.loop_closure_spacing_m; s < o.laps * lap; s += o.loop_closure_spacing_m) {
    const double t_to = scanNear(s / o.speed_mps);
    const double t_from = scanNear((o.speed_mps * t_to - lap + offset(rng)) / o.speed_mps);
    if (t_to + o.loop_closure_latency_sec > end_sec || t_from < 0) continue;
    LoopClosure msg = scanMatch(o, t_from, t_to, rng);
    robot->loop_closures.emplace_back(msg.header.stamp, std::move(msg));
  }
}

}  // namespace

std::optional<OdometryCovarianceStyle> odometryCovarianceStyleFromString(const std::string& s) {
  if (s == "constant") return OdometryCovarianceStyle::kConstant;
  if (s == "ekf_two_d") return OdometryCovarianceStyle::kEkfTwoD;
  if (s == "ekf_two_d_zero") return OdometryCovarianceStyle::kEkfTwoDZero;
  if (s == "zero") return OdometryCovarianceStyle::kZero;
  return std::nullopt;
}

std::string toString(OdometryCovarianceStyle style) {
  switch (style) {
    case OdometryCovarianceStyle::kConstant:
      return "constant";
    case OdometryCovarianceStyle::kEkfTwoD:
      return "ekf_two_d";
    case OdometryCovarianceStyle::kEkfTwoDZero:
      return "ekf_two_d_zero";
    case OdometryCovarianceStyle::kZero:
      return "zero";
  }
  return "?";
}

std::string PlanarRobotOptions::validate() const {
  if (laps < 2) return "laps must be >= 2 (loop closures join consecutive laps)";
  if (!positive(path.length) || !positive(path.width) || !positive(path.corner_radius) ||
      2 * path.corner_radius > std::min(path.length, path.width))
    return "path: length and width must be > 0 and at least twice the corner radius";
  if (!positive(speed_mps)) return "speed_mps must be > 0";
  if (!positive(odometry_rate_hz) || odometry_rate_hz > 1000) return "odometry_rate_hz must be in (0, 1000]";
  if (!positive(scan_rate_hz)) return "scan_rate_hz must be > 0";
  if (!nonNegative(scan_offset_sec) || scan_offset_sec >= 1.0 / scan_rate_hz)
    return "scan_offset_sec must be >= 0 and shorter than one scan period";
  for (double v : {odometry_translation_stddev_m, odometry_yaw_stddev_rad, loop_closure_translation_stddev_m,
                   loop_closure_yaw_stddev_rad})
    if (!positive(v)) return "the odometry and loop-closure standard deviations must be > 0";
  if (!std::isfinite(odometry_scale_error) || !std::isfinite(odometry_yaw_bias_rad_per_m))
    return "odometry_scale_error and odometry_yaw_bias_rad_per_m must be finite";
  if (!nonNegative(loop_closure_out_of_plane_stddev)) return "loop_closure_out_of_plane_stddev must be >= 0";
  if (!positive(loop_closure_spacing_m)) return "loop_closure_spacing_m must be > 0";
  if (!nonNegative(loop_closure_offset_m)) return "loop_closure_offset_m must be >= 0";
  if (!nonNegative(loop_closure_latency_sec)) return "loop_closure_latency_sec must be >= 0";
  if (!(std::isfinite(start_sec) && start_sec > 0 && start_sec < 4e9)) return "start_sec must be in (0, 4e9)";
  return "";
}

PlanarRobot makePlanarRobot(const PlanarRobotOptions& options) {
  const std::string invalid = options.validate();
  if (!invalid.empty()) throw std::invalid_argument(invalid);
  std::mt19937 odometry_rng(options.seed), loop_closure_rng(options.seed + 1000003u);
  PlanarRobot robot;
  addOdometry(options, odometry_rng, &robot);
  addLoopClosures(options, loop_closure_rng, &robot);
  return robot;
}

std::pair<double, double> odometryDrift(const PlanarRobot& robot) {
  double largest = 0.0, last = 0.0;
  for (std::size_t k = 0; k < robot.odometry.size(); ++k) {
    last = (poseFromMsg(robot.odometry[k].pose.pose).translation() - robot.truth[k].translation()).norm();
    largest = std::max(largest, last);
  }
  return {largest, last};
}

std::vector<std::string> writePlanarRobot(const PlanarRobot& robot, const std::string& bag_path) {
  try {
    rosbag::Bag bag(bag_path, rosbag::bagmode::Write);
    auto next = robot.loop_closures.begin();
    for (const nav_msgs::Odometry& odom : robot.odometry) {
      for (; next != robot.loop_closures.end() && next->first < odom.header.stamp; ++next)
        bag.write("/loop_closure", next->first, next->second);
      bag.write("/odom", odom.header.stamp, odom);
      bag.write("/tf", odom.header.stamp, tfFromOdometry(odom));
    }
    for (; next != robot.loop_closures.end(); ++next) bag.write("/loop_closure", next->first, next->second);
    bag.close();
  } catch (const rosbag::BagException& e) {
    throw std::runtime_error(bag_path + ": cannot write the bag: " + e.what());
  }
  // Scoring files: one node per odometry message, chained by its steps.
  const std::string stem = bagStem(bag_path);
  toro::PoseGraph truth, odometry;
  Sidecar sidecar;
  for (std::size_t k = 0; k < robot.odometry.size(); ++k) {
    const auto id = static_cast<toro::NodeId>(k);
    const toro::Pose3 odom_T_base = poseFromMsg(robot.odometry[k].pose.pose);
    truth.addNode(id, robot.truth[k]);
    odometry.addNode(id, odom_T_base);
    sidecar.keyframes.push_back(KeyframeRecord{id, robot.odometry[k].header.stamp, odom_T_base});
    if (k == 0) continue;
    truth.addConstraint(
        {id - 1, id, toro::relativePose(robot.truth[k - 1], robot.truth[k]), toro::Matrix6::Identity()});
    odometry.addConstraint(
        {id - 1, id, toro::relativePose(odometry.pose(id - 1), odom_T_base), toro::Matrix6::Identity()});
  }
  toro::writeGraph(truth, stem + ".truth.g2o");
  toro::writeGraph(odometry, stem + ".odometry.g2o");
  writeSidecar(sidecarPath(stem + ".odometry.g2o"), sidecar);
  return {bag_path, stem + ".truth.g2o", stem + ".odometry.g2o", sidecarPath(stem + ".odometry.g2o")};
}

}  // namespace offline
}  // namespace toro_ros
