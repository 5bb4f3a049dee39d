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

struct SampleOptions {
  int laps = 3;
  int closure_every = 3;  // keyframes between loop closures
  toro::NoiseOptions noise{0.05, 0.01, 42};
};

toro::SyntheticGraph makeSampleGraph(const SampleOptions& options);

}  // namespace offline
}  // namespace toro_ros
