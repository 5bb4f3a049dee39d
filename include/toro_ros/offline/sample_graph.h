// The bundled sample: a robot driving laps of a rounded 16 m x 8 m rectangle over a gentle hill
// (keyframes 1 m apart, 48 a lap), with seeded noisy odometry and a loop closure from every third
// keyframe to the same place on the previous lap.  Ground truth is known exactly: the graph's
// vertex poses are the truth (makeFromTrajectory, core/synthetic.h), so the written file serves as
// both the input and the --ground-truth of graph_to_bag.
#pragma once

#include <cstdint>

#include "toro_ros/core/synthetic.h"

namespace toro_ros {
namespace offline {

// A rectangle with rounded corners in the plane z = 0, centred at the origin, driven
// counter-clockwise from the middle of its bottom side (arc length s from there, any s; one lap is
// perimeter()).  The path of the bundled sample and of the planar robot (planar_robot.h).
struct RoundedRectangle {
  double length = 16.0;  // along x, m
  double width = 8.0;    // along y, m
  double corner_radius = 2.0;
  double perimeter() const;
  toro::Vector3 pointAt(double s) const;
};

struct SampleOptions {
  int laps = 3;
  int closure_every = 3;  // keyframes between loop closures
  toro::NoiseOptions noise{0.05, 0.01, 42};
};

toro::SyntheticGraph makeSampleGraph(const SampleOptions& options);

}  // namespace offline
}  // namespace toro_ros
