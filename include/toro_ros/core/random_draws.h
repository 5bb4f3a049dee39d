// Random draws in a fixed order.  `f(d(rng), d(rng), d(rng))` leaves the order of the draws to the
// compiler (C++ does not sequence a call's arguments): gcc draws the last argument first, clang the
// first, so one seed gave two different graphs (make_planar_robot, toro::makeSphere) and tests
// checked other data under the clang sanitizer build than under gcc.  These draw the last element
// first, the order gcc gave, so what gcc made before is unchanged.
#pragma once

#include <array>
#include <cstddef>

#include "toro_ros/core/pose3.h"

namespace toro {

// N values of `distribution`, element N-1 drawn first.
template <std::size_t N, class Distribution, class Rng>
std::array<typename Distribution::result_type, N> drawLastFirst(Distribution& distribution, Rng& rng) {
  std::array<typename Distribution::result_type, N> out{};
  for (std::size_t i = N; i-- > 0;) out[i] = distribution(rng);
  return out;
}

// A vector of three draws, z drawn first (as Vector3(d(rng), d(rng), d(rng)) was with gcc).
template <class Distribution, class Rng>
Vector3 drawVector3(Distribution& distribution, Rng& rng) {
  const auto v = drawLastFirst<3>(distribution, rng);
  return Vector3(v[0], v[1], v[2]);
}

// A pose of rotation vector drawn from `rotation` and translation from `translation`, the
// translation drawn first (as Pose3::fromAngleAxis(Vector3(r(rng), ...), Vector3(t(rng), ...)) was
// with gcc).
template <class RotationDistribution, class TranslationDistribution, class Rng>
Pose3 drawPose3(RotationDistribution& rotation, TranslationDistribution& translation, Rng& rng) {
  const Vector3 t = drawVector3(translation, rng);
  const Vector3 r = drawVector3(rotation, rng);
  return Pose3::fromAngleAxis(r, t);
}

}  // namespace toro
