// The planar test robot of issue 11: a wheeled robot driving laps of a 71.7 m rounded rectangle on
// a flat floor with drifting 20 Hz odometry, and a front end that finds loop closures between its
// own scans (10 Hz, stamped between odometry messages) a lap apart.  Everything is seeded and the
// truth is known exactly, so the error of a corrected map can be measured.
//
// Odometry.  Each 20 Hz increment of the true motion (d metres forward, a radians turned) is read
// with a systematic scale error and yaw bias (what calibration leaves) plus white noise of variance
// (d + |a|) * sigma^2 per axis (x, y, yaw in the robot's frame), and the readings are composed from
// the identity.  The noise is what the published covariances describe, in one of the ROS
// conventions (OdometryCovarianceStyle); the bias is what they cannot (it is why the map drifts).
//
// Loop closures.  From the second lap on, every loop_closure_spacing_m of path, the scan "now" is
// matched against the scan nearest to the same place one lap earlier (offset by up to
// loop_closure_offset_m along the path): the measurement is their true relative pose with planar
// noise (x, y, yaw), optionally out-of-plane noise (z, roll, pitch), and the covariance a 2D
// matcher publishes: its planar variances and 1e6 on z, roll and pitch.  It is published
// loop_closure_latency_sec after the later scan (the front end's processing time).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <nav_msgs/Odometry.h>

#include "toro_ros/LoopClosure.h"
#include "toro_ros/core/pose3.h"
#include "toro_ros/offline/sample_graph.h"

namespace toro_ros {
namespace offline {

// How the odometry messages' pose covariance is filled, as the common ROS sources do.
enum class OdometryCovarianceStyle {
  // diff_drive_controller: its pose_covariance_diagonal in every message, unchanged: here the noise
  // per metre + radian of motion on x, y and yaw, and 1e6 on z, roll and pitch.
  kConstant,
  // robot_localization's EKF in two_d_mode: x, y and yaw propagated as an EKF does (Jacobians of
  // the motion, so heading uncertainty grows into position and the correlations change), z, roll
  // and pitch held at 1e-6.
  kEkfTwoD,
  kEkfTwoDZero,  // the same with z, roll and pitch at 0
  kZero,         // all zero (many drivers leave it so)
};
// "constant" | "ekf_two_d" | "ekf_two_d_zero" | "zero"; nullopt for anything else.
std::optional<OdometryCovarianceStyle> odometryCovarianceStyleFromString(const std::string& s);
std::string toString(OdometryCovarianceStyle style);

struct PlanarRobotOptions {
  int laps = 3;
  RoundedRectangle path{26.0, 12.0, 2.5};  // 71.7 m a lap
  double speed_mps = 1.0;
  double odometry_rate_hz = 20.0;
  double scan_rate_hz = 10.0;
  double scan_offset_sec = 0.03;  // scans are stamped this long after an odometry message
  // Odometry errors: systematic (not in the covariance) and white (in it).
  double odometry_scale_error = 0.002;          // reads 0.2 % too far
  double odometry_yaw_bias_rad_per_m = 0.002;   // and turns left by this per metre driven
  double odometry_translation_stddev_m = 0.01;  // per sqrt(metre + radian), x and y
  double odometry_yaw_stddev_rad = 0.003;       // per sqrt(metre + radian)
  // Loop closures.
  double loop_closure_spacing_m = 1.4;  // of path between two loop closures (~100 in 3 laps)
  double loop_closure_offset_m = 0.5;   // the earlier scan is up to this far along the path
  double loop_closure_translation_stddev_m = 0.02;
  double loop_closure_yaw_stddev_rad = 0.003;
  double loop_closure_out_of_plane_stddev = 0.0;  // z in m and roll, pitch in rad; 0: none
  double loop_closure_latency_sec = 0.3;
  OdometryCovarianceStyle covariance_style = OdometryCovarianceStyle::kConstant;
  std::uint32_t seed = 1;
  double start_sec = 1000.0;
  std::string validate() const;  // empty when usable, else what is wrong (naming the option)
};

struct PlanarRobot {
  std::vector<nav_msgs::Odometry> odometry;                      // in stamp order, frame odom -> base_link
  std::vector<std::pair<ros::Time, LoopClosure>> loop_closures;  // (publish time, message), in time order
  std::vector<toro::Pose3> truth;  // world_T_base at each odometry stamp; world = odom at the start
  double path_length_m = 0.0;
};

// Throws std::invalid_argument naming the option if options.validate() complains.
PlanarRobot makePlanarRobot(const PlanarRobotOptions& options);

// The position error of the odometry against the truth, largest over the run and at the end (m).
std::pair<double, double> odometryDrift(const PlanarRobot& robot);

// Writes the bag (/odom, /tf, /loop_closure in time order, as graph_to_bag does) and, for scoring
// (scoring.h), "<stem>.truth.g2o" (the true pose at each odometry stamp) with
// "<stem>.odometry.g2o" (the odometry chain) and its stamps sidecar.  Returns the files written.
// Throws std::runtime_error naming the file on failure.
std::vector<std::string> writePlanarRobot(const PlanarRobot& robot, const std::string& bag_path);

}  // namespace offline
}  // namespace toro_ros
