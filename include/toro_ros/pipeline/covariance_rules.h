// How a ROS covariance (nav_msgs/Odometry pose, toro_ros/LoopClosure) becomes the core's
// information matrix, axis by axis.  ROS senders use the six diagonal entries in three ways:
//   - a real variance (measured axis): used, with its correlations to the other measured axes;
//   - a huge variance (>= the unmeasured_variance threshold, e.g. diff_drive_controller's 1e6 on z,
//     roll and pitch, robot_pose_ekf users' "1e3 to ignore an axis"): the sender does not measure
//     that axis.  It keeps the information the sender gave (~0: 1e6 gives 1e-6), never the defaults,
//     so a planar sensor does not pretend to know z; the label says so in the log and status, and
//     the core's optimisers can tell such axes by their information;
//   - zero, negative or not finite (unknown axis): the sender said nothing; that axis alone takes the
//     configured default standard deviation, uncorrelated (an infinite variance is unmeasured).
// Variances are clamped to [1e-6, 1e6] (m^2 / rad^2) before inverting, to bound the conditioning.
// The axes with a finite positive variance are inverted together, correlations included (a real
// covariance may be nearly singular: parking-garage's loop closures have rotation variances of 1e4
// from correlations alone).  A block that is not positive definite (an EKF's covariance difference
// often is not) is repaired rather than thrown away: its variances are kept and all its
// correlations shrunk by one factor until the smallest eigenvalue of its correlation matrix is
// kRepairedCorrelationEigenvalue.
#pragma once

#include <array>
#include <string>

#include "toro_ros/core/pose3.h"

namespace toro_ros {

// Standard deviations used on axes whose covariance is unknown (zero, negative, not finite).
struct DefaultStddev {
  double translation_m = 0.05;
  double rotation_rad = 0.02;
  std::string validate() const;  // empty when both are finite and > 0
};

// Variances at or above this (m^2 or rad^2) mean "not measured" unless configured otherwise.
constexpr double kDefaultUnmeasuredVariance = 1e3;
// A correlation matrix whose smallest eigenvalue is below this is not positive definite (to
// rounding) and is repaired: shrunk until its smallest eigenvalue is kRepairedCorrelationEigenvalue,
// so no combination of axes gets more than 10 times the information its axes' variances give.
constexpr double kSingularCorrelation = 1e-12;
constexpr double kRepairedCorrelationEigenvalue = 0.1;

enum class AxisReading { kMeasured, kUnmeasured, kUnknown };
using AxisReadings = std::array<AxisReading, 6>;

// Result of turning a covariance into the core's information matrix.
struct InformationResult {
  toro::Matrix6 information;  // g2o order, rotation block in quaternion-vector units
  AxisReadings axes{AxisReading::kUnknown, AxisReading::kUnknown, AxisReading::kUnknown,
                    AxisReading::kUnknown, AxisReading::kUnknown, AxisReading::kUnknown};
  int default_axes = 0;       // axes that took the default (kUnknown)
  bool used_default = false;  // all six did (nothing in the covariance was usable)
  bool repaired = false;      // correlations were shrunk, averaged or dropped
  std::string reason;         // why axes took defaults or were repaired (empty otherwise)
};

// Diagonal information of the defaults, in the core's units.
toro::Matrix6 defaultInformation(const DefaultStddev& defaults);

// The reading of each axis from its variance alone (the diagonal entry): see the file comment.
AxisReadings readAxes(const toro::Matrix6& covariance, double unmeasured_variance);

// Covariance in geometry_msgs order and units (x y z, rotation about X Y Z in rad) -> the core's
// information, with `axes` saying how to read each axis (readAxes, or a caller's own reading, e.g.
// the keyframer's "did not grow" for a covariance difference).  The core's rotational error is the
// quaternion vector part, about half the rotation vector, so with J = diag(1,1,1,1/2,1/2,1/2):
// Omega_q = J^-T Sigma^-1 J^-1, i.e. the rotation block times 4 and the cross blocks times 2.
// Always returns a finite, symmetric, positive definite information.
InformationResult informationFromAxes(const toro::Matrix6& covariance, const AxisReadings& axes,
                                      const DefaultStddev& defaults);

// readAxes then informationFromAxes.
InformationResult informationFromCovariance(const toro::Matrix6& covariance, const DefaultStddev& defaults,
                                            double unmeasured_variance = kDefaultUnmeasuredVariance);

// A pose covariance (odom frame, translation then rotation about X Y Z) carried over a displacement
// of the position, as an EKF's prediction carries it: a rotation error d_theta at the start moves
// the end by d_theta x displacement (F = [I, -[displacement]x; 0, I], Sigma -> F Sigma F^T).
toro::Matrix6 carriedCovariance(const toro::Matrix6& covariance, const toro::Vector3& displacement);

// "x y z" style list of the axes with the given reading ("" if none).
std::string axisNames(const AxisReadings& axes, AxisReading reading);
// One line: "measured x y yaw; unmeasured z roll pitch (variance >= 1000)"; unknown ones too.
std::string describeAxes(const AxisReadings& axes, double unmeasured_variance);

}  // namespace toro_ros
