// Wrong loop closures for benchmarks and tests: what a place recogniser that is sometimes wrong
// would add to a pose graph.  Seeded, so a table can be reproduced.
//
// Every wrong loop closure borrows its measurement and information from a randomly chosen loop
// closure of the graph (from an odometry constraint when it has none): it looks like a real one to
// any test on its own, so only its disagreement with the rest of the graph gives it away.
//   kRandom   between two random poses (at least two ids apart);
//   kLocal    between a pose and one 2..local_max_offset ids later (a recogniser confusing nearby,
//             similar-looking places);
//   kGrouped  groups of group_size mutually consistent ones: pose pairs (i + a, j + a), a = 0 ..
//             group_size - 1, whose measurements all agree with one wrong relative pose of (i, j)
//             moved along the reference trajectory (a repeated wrong match along a corridor), so
//             each supports the others.
// 2D graphs stay 2D: borrowed measurements are planar, and grouped ones are composed in the plane.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "toro_ros/core/pose_graph.h"

namespace toro {

enum class OutlierKind { kRandom, kLocal, kGrouped };
// "random" | "local" | "grouped"
std::optional<OutlierKind> outlierKindFromString(const std::string& name);
const char* outlierKindName(OutlierKind kind);

struct OutlierOptions {
  OutlierKind kind = OutlierKind::kRandom;
  std::size_t count = 100;
  std::uint32_t seed = 1;
  int local_max_offset = 10;  // kLocal: the later pose is 2..local_max_offset ids on
  std::size_t group_size = 10;  // kGrouped (count is rounded up to whole groups)
};

struct GraphWithOutliers {
  PoseGraph graph;                       // the input plus the wrong loop closures at the end
  std::vector<std::size_t> outliers;     // their constraint indices
};

// `reference` supplies the poses that grouped outliers are moved along (e.g. the clean optimum);
// null: the graph's own poses.  Throws std::invalid_argument for a graph with fewer than
// 2 * group_size + 4 nodes or no constraints.
GraphWithOutliers addOutliers(const PoseGraph& graph, const OutlierOptions& options,
                              const PoseGraph* reference = nullptr);

}  // namespace toro
