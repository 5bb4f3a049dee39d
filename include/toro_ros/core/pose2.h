// SE(2) value type of the planar optimiser: a unit complex number (cos, sin of the heading) and a
// translation in the plane.  Its interface mirrors Pose3 (rotation(), translation(), operator*,
// inverse(), setRotationUnchecked, renormalize) so that the tree optimiser's update is one piece
// of code for both groups (tree_groups.h).  Keeping cos and sin rather than the angle makes
// composition trigonometry-free, as the quaternion does in 3D.
//
// Convention as Pose3: `a_T_b` maps coordinates in frame b to frame a.
#pragma once

#include <cmath>

#include <Eigen/Core>

#include "toro_ros/core/pose3.h"

namespace toro {

using Vector2 = Eigen::Vector2d;
using Matrix2 = Eigen::Matrix2d;

// A planar rotation as the unit complex number cos + i sin.
class Rotation2 {
 public:
  Rotation2() = default;
  // The caller guarantees cos^2 + sin^2 = 1 (to rounding).
  Rotation2(double cos, double sin) : cos_(cos), sin_(sin) {}
  static Rotation2 Identity() { return Rotation2(); }
  static Rotation2 fromAngle(double theta) { return Rotation2(std::cos(theta), std::sin(theta)); }

  double cos() const { return cos_; }
  double sin() const { return sin_; }
  // In [-pi, pi].  Near the identity (the optimiser's residuals) by series, several times faster
  // than atan2 and within rounding of it: below 2e-3 rad the arcsine series of sin (three terms,
  // remainder 15 sin^7 / 336 < 1e-20; no division, the usual case once TORO has settled), below
  // 0.1 rad the arctangent series of t = sin / cos (eight terms, remainder t^17 / 17 < 1e-18).
  double angle() const {
    constexpr double k3 = -1.0 / 3, k5 = 1.0 / 5, k7 = -1.0 / 7, k9 = 1.0 / 9, k11 = -1.0 / 11,
                     k13 = 1.0 / 13, k15 = -1.0 / 15;
    if (cos_ > 0.0 && std::abs(sin_) < 2e-3) {
      const double s2 = sin_ * sin_;
      return sin_ + sin_ * s2 * (1.0 / 6 + s2 * (3.0 / 40));
    }
    if (cos_ > 0.0 && std::abs(sin_) < 0.1 * cos_) {
      const double t = sin_ / cos_;
      const double t2 = t * t;
      const double t4 = t2 * t2;  // Estrin's scheme: a shorter chain of dependent operations
      const double p = (k3 + t2 * k5) + t4 * (k7 + t2 * k9) + t4 * t4 * ((k11 + t2 * k13) + t4 * k15);
      return t + t * t2 * p;
    }
    return std::atan2(sin_, cos_);
  }

  Rotation2 operator*(const Rotation2& o) const {
    return Rotation2(cos_ * o.cos_ - sin_ * o.sin_, sin_ * o.cos_ + cos_ * o.sin_);
  }
  // As packed arithmetic (cos v + sin v_perp), which the compiler keeps in registers: built from
  // two separately computed scalars, the result went through memory (a store-forwarding stall).
  Vector2 operator*(const Vector2& v) const { return cos_ * v + sin_ * Vector2(-v.y(), v.x()); }
  Rotation2 conjugate() const { return Rotation2(cos_, -sin_); }
  Matrix2 toRotationMatrix() const {
    Matrix2 r;
    r << cos_, -sin_, sin_, cos_;
    return r;
  }
  double squaredNorm() const { return cos_ * cos_ + sin_ * sin_; }
  // First-order re-normalisation, as Pose3::renormalize (for values within rounding of unit length).
  void renormalize() {
    const double k = 0.5 * (3.0 - squaredNorm());
    cos_ *= k;
    sin_ *= k;
  }

 private:
  double cos_ = 1.0;
  double sin_ = 0.0;
};

// Rotation by `theta` rad.  Below 0.1 rad by the Taylor series (as quaternionFromRotationVector):
// the optimiser's per-node increments are small, and the series is several times faster than
// sin and cos.  Below 2e-3 rad (most increments once TORO has settled) three terms each
// (truncation theta^6 / 720 < 1e-19), else five (theta^10 / 10!, theta^11 / 11! < 1e-16).
inline Rotation2 rotation2FromAngle(double theta) {
  constexpr double c2 = -1.0 / 2, c4 = 1.0 / 24, c6 = -1.0 / 720, c8 = 1.0 / 40320;
  constexpr double s3 = -1.0 / 6, s5 = 1.0 / 120, s7 = -1.0 / 5040, s9 = 1.0 / 362880;
  const double t2 = theta * theta;
  if (t2 < 4e-6) return Rotation2(1.0 + t2 * (c2 + t2 * c4), theta + theta * t2 * (s3 + t2 * s5));
  if (t2 < 0.01) {
    const double t4 = t2 * t2;
    const double c = 1.0 + t2 * (c2 + t2 * c4) + t4 * t2 * (c6 + t2 * c8);
    const double s = theta + theta * t2 * ((s3 + t2 * s5) + t4 * (s7 + t2 * s9));
    return Rotation2(c, s);
  }
  return Rotation2(std::cos(theta), std::sin(theta));
}

class Pose2 {
 public:
  Pose2() : translation_(Vector2::Zero()) {}
  Pose2(const Rotation2& rotation, const Vector2& translation)
      : rotation_(rotation), translation_(translation) {}
  static Pose2 fromXYTheta(double x, double y, double theta) {
    return Pose2(Rotation2::fromAngle(theta), Vector2(x, y));
  }

  const Rotation2& rotation() const { return rotation_; }
  const Vector2& translation() const { return translation_; }
  double angle() const { return rotation_.angle(); }
  void setRotationUnchecked(const Rotation2& r) { rotation_ = r; }
  void setTranslation(const Vector2& t) { translation_ = t; }

  Pose2 operator*(const Pose2& o) const {
    return Pose2(rotation_ * o.rotation_, translation_ + rotation_ * o.translation_);
  }
  Vector2 operator*(const Vector2& point) const { return translation_ + rotation_ * point; }
  Pose2 inverse() const {
    const Rotation2 r = rotation_.conjugate();
    return Pose2(r, -(r * translation_));
  }
  bool isFinite() const {
    return std::isfinite(rotation_.cos()) && std::isfinite(rotation_.sin()) && translation_.allFinite();
  }
  void renormalize() { rotation_.renormalize(); }

 private:
  Rotation2 rotation_;
  Vector2 translation_;
};

// The planar part of a 3D pose: (x, y) and the heading of the x axis in the plane (the yaw of
// R = Rz(yaw) Ry(pitch) Rx(roll)); z, roll and pitch are dropped.  Exact for a pose of the plane.
Pose2 planarPart(const Pose3& pose);
// The pose of the plane z = 0 (roll = pitch = 0 exactly): quaternion (w, 0, 0, z), translation (x, y, 0).
inline Pose3 liftToPose3(const Pose2& pose) {
  // Half-angle formulas for the quaternion (cos(theta/2), 0, 0, sin(theta/2)), taking the larger of
  // the two components from its square root so that neither is computed from a small one.
  const double c = pose.rotation().cos(), s = pose.rotation().sin();
  double w, z;
  if (c >= 0.0) {
    w = std::sqrt(0.5 * (1.0 + c));
    z = s / (2.0 * w);
  } else {
    z = std::copysign(std::sqrt(0.5 * (1.0 - c)), s);
    w = s / (2.0 * z);
  }
  Pose3 out;
  out.setRotationUnchecked(Quaternion(w, 0.0, 0.0, z));
  out.setTranslation(Vector3(pose.translation().x(), pose.translation().y(), 0.0));
  return out;
}

}  // namespace toro
