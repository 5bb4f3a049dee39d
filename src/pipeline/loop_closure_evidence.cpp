#include "toro_ros/pipeline/loop_closure_evidence.h"

#include <cmath>
#include <limits>

#include "toro_ros/core/chi_square.h"

namespace toro_ros {

namespace {

// The statistics' samples: the newest this many tests, and the quantile read (see pairThreshold).
constexpr std::size_t kPairSample = 1000;
constexpr double kSupportScaleQuantile = 0.2;
// A loop closure weighted below this on the map's tree path is no evidence there (mapPathVerdict
// cannot tell): its covariance would be inflated past meaning.
constexpr double kPathLinkMinWeight = 0.1;
// The path and odometry vetoes' scale (see kPathLenience) is read once this many were tested, and
// never below kMinPathScale.
constexpr std::size_t kMinPathsToScale = 10;
constexpr double kMinPathScale = 1e-12;
// Longer tree paths are not composed (the cost is linear in the links): so long a path is
// compliant, so it would seldom veto.
constexpr std::size_t kMaxPathLinks = 5000;

}  // namespace

LoopClosureEvidence::LoopClosureEvidence(const toro::TreeOptimizer& map,
                                         const std::vector<bool>& is_loop_closure, bool planar)
    : map_(map),
      is_loop_closure_(is_loop_closure),
      planar_(planar),
      odometry_(planar),
      tested_pairs_(kPairSample, kSupportScaleQuantile),
      tested_paths_(kPairSample, kSupportScaleQuantile),
      tested_odometry_paths_(kPairSample, kSupportScaleQuantile) {}

void LoopClosureEvidence::clear() {
  forgetStructure();
  tested_pairs_.clear();
  tested_paths_.clear();
  tested_odometry_paths_.clear();
}

void LoopClosureEvidence::forgetStructure() {
  odometry_.clear();
  odometry_cycle_chi2_.clear();
}

const toro::OdometryChain& LoopClosureEvidence::odometry() {
  const toro::PoseGraph& g = map_.graph();
  for (std::size_t v = odometry_.size(); v < g.numNodes(); ++v) {
    std::size_t step = toro::kNoOdometry;
    if (v > 0)
      for (std::size_t c : map_.incident(v))
        if (!is_loop_closure_[c] && std::min(map_.fromIndex(c), map_.toIndex(c)) == v - 1) {
          step = c;
          break;
        }
    odometry_.append(g, step);
  }
  return odometry_;
}

std::size_t LoopClosureEvidence::span(std::size_t c) const {
  const std::size_t a = map_.fromIndex(c), b = map_.toIndex(c);
  return a > b ? a - b : b - a;
}

double LoopClosureEvidence::odometryCycleChi2(std::size_t c) {
  if (odometry_cycle_chi2_.size() <= c)
    odometry_cycle_chi2_.resize(c + 1, std::numeric_limits<double>::quiet_NaN());
  double& chi2 = odometry_cycle_chi2_[c];
  // Measurements only, so it never changes while the constraints stay as they are.
  if (std::isnan(chi2)) chi2 = toro::loopClosureOdometryChi2(map_.graph(), odometry(), c);
  return chi2;
}

double LoopClosureEvidence::pairChi2(std::size_t c, std::size_t j) {
  return toro::loopClosurePairChi2(map_.graph(), odometry(), c, j);
}

double LoopClosureEvidence::mapPathChi2(std::size_t c) {
  const toro::ParameterTree& tree = map_.tree();
  const std::size_t a = map_.fromIndex(c), b = map_.toIndex(c);
  if (tree.path(a, b, path_up_, path_down_) == toro::ParameterTree::kNone) return -1.0;
  if (path_up_.size() + path_down_.size() > kMaxPathLinks) return -1.0;
  // The link between a node and its tree parent: the weightiest constraint between them that
  // counts (a held loop closure is not evidence; c is what is judged).
  bool through_loop_closure = false;
  const auto link = [&](std::size_t child) {
    const std::size_t parent = tree.parent(child);
    toro::ChainLink best{0, 0.0};
    for (std::size_t j : map_.incident(child)) {
      if (j == c || map_.weightCap(j) < 1.0) continue;
      if ((map_.fromIndex(j) == child ? map_.toIndex(j) : map_.fromIndex(j)) != parent) continue;
      const double w = is_loop_closure_[j] ? map_.weights()[j] : 1.0;
      if (w > best.weight) best = {j, w};
    }
    if (!(best.weight >= kPathLinkMinWeight)) return false;
    if (is_loop_closure_[best.constraint]) through_loop_closure = true;
    path_links_.push_back(best);
    return true;
  };
  path_links_.clear();
  for (std::size_t u : path_up_)
    if (!link(u)) return -1.0;
  const std::size_t up_links = path_links_.size();
  for (std::size_t w : path_down_)
    if (!link(w)) return -1.0;
  if (!through_loop_closure) return -1.0;  // odometry alone: odometryCycleChi2 says the same, cached
  std::reverse(path_links_.begin() + static_cast<std::ptrdiff_t>(up_links), path_links_.end());  // top -> b
  return toro::loopClosureChainChi2(map_.graph(), c, path_links_, planar_);
}

double LoopClosureEvidence::declaredQuantile(double dof) {
  return toro::chiSquareQuantile(kSupportConfidence, dof);
}

double LoopClosureEvidence::pairThreshold(double dof) const {
  const double quantile = toro::chiSquareQuantile(kSupportConfidence, dof);
  // samples() <= count(): cycles closed to rounding are counted but are no sample of the scale.
  if (tested_pairs_.samples() < kMinPairsToAdaptSupport) return quantile;
  // Senders whose covariances are far too large (parking-garage.g2o: residuals ~1e-4 of the
  // declared ones) make every cycle look consistent, wrong ones too: the threshold narrows by the
  // ratio of the tested pairs' low quantile to the chi-square's, never widens.  All tested pairs,
  // not only those that agreed (a statistic of what passed would narrow itself), and a low
  // quantile, not the median: wrong loop closures near each other test many pairs too (1000
  // random ones on intel outnumber the right pairs), but their cycles are large, so the lowest
  // fifth is the right pairs' as long as they make a fifth of all.
  const double ratio =
      kSupportLenience * tested_pairs_.lowQuantile() / toro::chiSquareQuantile(kSupportScaleQuantile, dof);
  return quantile * std::min(1.0, ratio);
}

double LoopClosureEvidence::pathThreshold(bool through_loop_closure, double dof) const {
  const RecentChi2& tested = through_loop_closure ? tested_paths_ : tested_odometry_paths_;
  const double lenience = through_loop_closure ? kPathLenience : kOdometryPathLenience;
  const double declared = lenience * toro::chiSquareQuantile(kSupportConfidence, dof);
  if (tested.samples() < kMinPathsToScale) return declared;
  const double scale = tested.lowQuantile() / toro::chiSquareQuantile(kSupportScaleQuantile, dof);
  return declared * std::clamp(scale, kMinPathScale, 1.0);
}

}  // namespace toro_ros
