#include "toro_ros/pipeline/covariance_rules.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include "toro_ros/core/pose_graph.h"

namespace toro_ros {

namespace {

// Variances are clamped into [kMinVariance, kMaxVariance] before inverting.  Below, a pose-graph
// measurement is not known better than 1 mm / 1 mrad, and more information adds nothing but
// ill-conditioning; above, the axis is unmeasured anyway (1e6 is what diff_drive_controller and 2D
// matchers publish) and its information must stay > 0.  So the information's condition number is
// at most ~1e14 (with the correlation repair's factor 10 and the quaternion units' 4), which keeps
// it positive definite to rounding in every solver that checks it.
constexpr double kMinVariance = 1e-6;
constexpr double kMaxVariance = 1e6;
// Relative asymmetry of a covariance that is rounding, not a wrong layout.
constexpr double kSymmetryTolerance = 1e-9;

const char* const kAxisNames[6] = {"x", "y", "z", "roll", "pitch", "yaw"};

double clampedVariance(double v) { return std::min(std::max(v, kMinVariance), kMaxVariance); }

// The information (angle units) of the axes with a finite positive variance, measured or not: the
// sender's covariance inverted as it is, so a 1e6 variance gives 1e-6 and strong correlations of a
// real covariance are kept.  Only a block that is not positive definite is repaired.
Eigen::MatrixXd blockInformation(const toro::Matrix6& covariance, const std::vector<int>& block,
                                 InformationResult* out) {
  const int n = static_cast<int>(block.size());
  Eigen::VectorXd raw(n), stddev(n);
  for (int a = 0; a < n; ++a) {
    raw(a) = std::sqrt(covariance(block[a], block[a]));
    stddev(a) = std::sqrt(clampedVariance(covariance(block[a], block[a])));
  }
  Eigen::MatrixXd correlation = Eigen::MatrixXd::Identity(n, n);
  bool dropped = false, averaged = false, clamped = false;
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < n; ++b) {
      const double ab = covariance(block[a], block[b]), ba = covariance(block[b], block[a]);
      if (!std::isfinite(ab) || !std::isfinite(ba)) {
        dropped = true;
        continue;
      }
      const double scale = raw(a) * raw(b);
      if (std::abs(ab - ba) > kSymmetryTolerance * scale) averaged = true;
      // Variances near the underflow limit (a fuzzer's 1e-320) make the ratio overflow: no
      // correlation can be read from them.  One beyond +-1 is impossible: clamped, then repaired
      // below with the rest (an unbounded one would survive the shrink's rounding).
      const double c = 0.5 * (ab + ba) / scale;
      if (!std::isfinite(c)) {
        dropped = true;
        continue;
      }
      if (std::abs(c) > 1.0) clamped = true;
      correlation(a, b) = correlation(b, a) = std::max(-1.0, std::min(1.0, c));
    }
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(correlation, Eigen::EigenvaluesOnly);
  const double smallest = eigen.info() == Eigen::Success ? eigen.eigenvalues().minCoeff() : -1.0;
  const bool shrunk = !(smallest >= kSingularCorrelation);
  if (shrunk) {
    // Shrink every correlation by the same factor, towards none, until the smallest eigenvalue is
    // kRepairedCorrelationEigenvalue: the eigenvectors stay, the variances stay, and no
    // combination of axes gets more than 1 / that times the information its axes give.
    const double alpha =
        eigen.info() == Eigen::Success ? (kRepairedCorrelationEigenvalue - smallest) / (1.0 - smallest) : 1.0;
    const Eigen::MatrixXd identity = Eigen::MatrixXd::Identity(n, n);
    correlation = (1.0 - alpha) * correlation + alpha * identity;
  }
  if (dropped || averaged || clamped || shrunk) {
    out->repaired = true;
    std::string why;
    if (dropped) why += "non-finite correlations dropped";
    if (clamped) why += std::string(why.empty() ? "" : ", ") + "correlations beyond +-1 clamped";
    if (averaged) why += std::string(why.empty() ? "" : ", ") + "asymmetric correlations averaged";
    if (shrunk) why += std::string(why.empty() ? "" : ", ") + "correlations shrunk (not positive definite)";
    out->reason += std::string(out->reason.empty() ? "" : "; ") + why;
  }
  Eigen::MatrixXd correlation_inverse = correlation.llt().solve(Eigen::MatrixXd::Identity(n, n));
  correlation_inverse = 0.5 * (correlation_inverse + correlation_inverse.transpose()).eval();
  const Eigen::VectorXd s_inv = stddev.cwiseInverse();
  return s_inv.asDiagonal() * correlation_inverse * s_inv.asDiagonal();
}

}  // namespace

std::string DefaultStddev::validate() const {
  if (!(std::isfinite(translation_m) && translation_m > 0)) return "default translation stddev must be > 0";
  if (!(std::isfinite(rotation_rad) && rotation_rad > 0)) return "default rotation stddev must be > 0";
  return "";
}

toro::Matrix6 defaultInformation(const DefaultStddev& defaults) {
  toro::Matrix6 info = toro::Matrix6::Zero();
  const double wt = 1.0 / (defaults.translation_m * defaults.translation_m);
  // Per rad^2 on the angle is 4x per unit^2 on the quaternion vector (see header).
  const double wr = 4.0 / (defaults.rotation_rad * defaults.rotation_rad);
  info.diagonal() << wt, wt, wt, wr, wr, wr;
  return info;
}

AxisReadings readAxes(const toro::Matrix6& covariance, double unmeasured_variance) {
  AxisReadings axes;
  for (int i = 0; i < 6; ++i) {
    const double v = covariance(i, i);
    if (v == std::numeric_limits<double>::infinity() || (std::isfinite(v) && v >= unmeasured_variance))
      axes[i] = AxisReading::kUnmeasured;
    else if (std::isfinite(v) && v > 0)
      axes[i] = AxisReading::kMeasured;
    else
      axes[i] = AxisReading::kUnknown;  // zero, negative, NaN or -inf
  }
  return axes;
}

InformationResult informationFromAxes(const toro::Matrix6& covariance, const AxisReadings& axes,
                                      const DefaultStddev& defaults) {
  InformationResult out;
  out.axes = axes;
  toro::Matrix6 per_angle = toro::Matrix6::Zero();
  std::vector<int> block;  // axes inverted together: a finite positive variance, measured or not
  for (int i = 0; i < 6; ++i) {
    const double v = covariance(i, i);
    if (out.axes[i] != AxisReading::kUnknown && !(v > 0 && !std::isnan(v)))
      out.axes[i] = AxisReading::kUnknown;
    if (out.axes[i] == AxisReading::kMeasured && !std::isfinite(v)) out.axes[i] = AxisReading::kUnmeasured;
    if (out.axes[i] == AxisReading::kUnknown) {
      const double stddev = i < 3 ? defaults.translation_m : defaults.rotation_rad;
      per_angle(i, i) = 1.0 / (stddev * stddev);
      ++out.default_axes;
    } else if (std::isfinite(v)) {
      block.push_back(i);
    } else {
      per_angle(i, i) = 1.0 / kMaxVariance;  // an infinite variance: unmeasured, uncorrelated
    }
  }
  if (out.default_axes > 0)
    out.reason = (out.default_axes == 6 ? std::string("no usable variance")
                                        : axisNames(out.axes, AxisReading::kUnknown) + " unknown") +
                 " (zero, negative or not finite): defaults";
  out.used_default = out.default_axes == 6;
  if (!block.empty()) {
    const Eigen::MatrixXd information = blockInformation(covariance, block, &out);
    for (std::size_t a = 0; a < block.size(); ++a)
      for (std::size_t b = 0; b < block.size(); ++b)
        per_angle(block[a], block[b]) = information(static_cast<int>(a), static_cast<int>(b));
  }
  // Exactly symmetric (the products above round differently on the two sides).
  out.information = toro::angleToQuaternionUnits(0.5 * (per_angle + per_angle.transpose()));
  return out;
}

InformationResult informationFromCovariance(const toro::Matrix6& covariance, const DefaultStddev& defaults,
                                            double unmeasured_variance) {
  return informationFromAxes(covariance, readAxes(covariance, unmeasured_variance), defaults);
}

toro::Matrix6 carriedCovariance(const toro::Matrix6& covariance, const toro::Vector3& displacement) {
  toro::Matrix6 carry = toro::Matrix6::Identity();
  carry.block<3, 3>(0, 3) << 0, displacement.z(), -displacement.y(), -displacement.z(), 0, displacement.x(),
      displacement.y(), -displacement.x(), 0;
  return carry * covariance * carry.transpose();
}

std::string axisNames(const AxisReadings& axes, AxisReading reading) {
  std::string out;
  for (int i = 0; i < 6; ++i)
    if (axes[i] == reading) out += std::string(out.empty() ? "" : " ") + kAxisNames[i];
  return out;
}

std::string describeAxes(const AxisReadings& axes, double unmeasured_variance) {
  std::string out;
  auto add = [&](AxisReading r, const std::string& label) {
    const std::string names = axisNames(axes, r);
    if (!names.empty()) out += std::string(out.empty() ? "" : "; ") + label + " " + names;
  };
  char threshold[32];
  std::snprintf(threshold, sizeof(threshold), "%g", unmeasured_variance);
  add(AxisReading::kMeasured, "measured:");
  add(AxisReading::kUnmeasured, std::string("unmeasured (variance >= ") + threshold + ", information ~0):");
  add(AxisReading::kUnknown, "unknown (zero or not finite, defaults):");
  return out;
}

}  // namespace toro_ros
