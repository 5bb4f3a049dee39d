#include "toro_ros/core/pairwise_consistency.h"

#include <algorithm>

#include "toro_ros/core/chi_square.h"
#include "toro_ros/core/loop_closure_pairs.h"

namespace toro {

PairwiseConsistency pairwiseConsistency(const PoseGraph& graph) {
  const std::size_t n = graph.numNodes(), m = graph.numConstraints();
  const bool planar = graph.dimension() == GraphDimension::k2D;
  const double dof = planar ? 3.0 : 6.0;
  std::vector<bool> is_loop_closure(m);
  std::vector<std::size_t> from(m), to(m);
  std::vector<std::vector<std::size_t>> incident(n);  // loop closures at each dense node
  for (std::size_t c = 0; c < m; ++c) {
    const Constraint& k = graph.constraints()[c];
    is_loop_closure[c] = isLoopClosure(k);
    from[c] = graph.indexOf(k.from);
    to[c] = graph.indexOf(k.to);
    if (!is_loop_closure[c]) continue;
    incident[from[c]].push_back(c);
    incident[to[c]].push_back(c);
  }
  const OdometryChain odometry(graph, is_loop_closure, planar);
  const auto near = [](std::size_t x, std::size_t y) { return (x > y ? x - y : y - x) <= kPairWindowNodes; };

  // Every pair once (the partner with the larger index is tested from the smaller); ends a few
  // nodes apart ask the odometry between them instead.
  std::vector<std::vector<double>> cycles(m);
  std::vector<double> short_span(m, -1.0);
  std::vector<double> all;
  for (std::size_t c = 0; c < m; ++c) {
    if (!is_loop_closure[c]) continue;
    const std::size_t a = std::min(from[c], to[c]), b = std::max(from[c], to[c]);
    if (b - a <= kPairWindowNodes) {
      short_span[c] = loopClosureOdometryChi2(graph, odometry, c);
      continue;
    }
    // Nearest first: the shortest odometry between the near ends, the cheapest and most precise
    // cycles.
    for (std::size_t d = 0; d <= 2 * kPairWindowNodes && cycles[c].size() < kMaxPairsPerLoopClosure; ++d) {
      const std::size_t offset = (d + 1) / 2;
      if (d % 2 == 1 ? offset > a : a + offset >= n) continue;
      const std::size_t u = d % 2 == 1 ? a - offset : a + offset;
      for (std::size_t j : incident[u]) {
        if (j <= c || cycles[c].size() >= kMaxPairsPerLoopClosure) continue;
        const std::size_t other = from[j] == u ? to[j] : from[j];
        if (!near(other, b) || std::minmax(u, other) == std::minmax(a, b)) continue;
        const double chi2 = loopClosurePairChi2(graph, odometry, c, j);
        if (!(chi2 >= 0.0)) continue;  // the odometry does not join the near ends
        cycles[c].push_back(chi2);
        cycles[j].push_back(chi2);
        all.push_back(chi2);
      }
    }
  }

  PairwiseConsistency out;
  out.pairs_tested = all.size();
  out.verdicts.assign(m, PairVerdict::kNotALoopClosure);
  for (std::size_t c = 0; c < m; ++c)
    if (is_loop_closure[c]) out.verdicts[c] = PairVerdict::kAlone;
  if (all.size() < kMinPairsForScale) return out;
  // All tested cycles, not only agreeing ones (a statistic of what passed would narrow itself);
  // a low quantile, as wrong loop closures near each other make cycles too, but large ones.
  const std::size_t k = static_cast<std::size_t>(kPairScaleQuantile * static_cast<double>(all.size() - 1));
  std::nth_element(all.begin(), all.begin() + static_cast<std::ptrdiff_t>(k), all.end());
  out.scale = std::min(1.0, kPairScaleLenience * all[k] / chiSquareQuantile(kPairScaleQuantile, dof));
  out.scale_learnt = true;
  const double threshold = chiSquareQuantile(kPairConfidence, dof) * out.scale;
  for (std::size_t c = 0; c < m; ++c) {
    if (!is_loop_closure[c]) continue;
    if (short_span[c] >= 0.0) {
      out.verdicts[c] = short_span[c] <= threshold ? PairVerdict::kAgreed : PairVerdict::kContradicted;
      continue;
    }
    if (cycles[c].empty()) continue;  // alone (a short span the odometry does not join, too)
    const auto agreeing =
        std::count_if(cycles[c].begin(), cycles[c].end(), [&](double x) { return x <= threshold; });
    out.verdicts[c] = static_cast<std::size_t>(agreeing) >= kMinAgreeingPartners ? PairVerdict::kAgreed
                                                                                 : PairVerdict::kContradicted;
  }
  return out;
}

}  // namespace toro
