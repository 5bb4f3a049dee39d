// Robust weights for loop closures: a place recogniser is sometimes wrong, and a wrong loop closure
// weighted as a Gaussian bends the whole map.  Each loop closure's information is scaled by a
// weight w(chi2) in [0, 1] from its current residual chi2 = e^T Omega e (g2o units); odometry stays
// Gaussian (w = 1).  Both optimisers use the same weights: TORO scales a constraint's step and its
// share of the preconditioner by w, the sparse finish minimises sum rho(chi2) by iteratively
// reweighted Levenberg-Marquardt (w = rho'(chi2)).  Kernels and their widths (phi, in chi2 units):
//   DCS     Dynamic Covariance Scaling (Agarwal, Tipaldi, Spinello, Stachniss, Burgard, ICRA 2013):
//           w = min(1, (2 phi / (phi + chi2))^2), the closed-form optimum of a switchable constraint;
//           rho = chi2 up to phi, then 3 phi - 4 phi^2 / (phi + chi2) (bounded: a wrong loop closure
//           can never cost more than 3 phi, so it cannot drag the map).
//   Cauchy  w = 1 / (1 + chi2 / phi), rho = phi log(1 + chi2 / phi) (unbounded, slowly growing).
//   Huber   w = min(1, sqrt(phi / chi2)); convex, for reference: it limits, but never rejects.
// A loop closure counts as rejected when its weight is below kRejectedWeight.
#pragma once

#include <optional>
#include <string>

namespace toro {

enum class RobustKernel { kNone, kDcs, kCauchy, kHuber };

// "none" | "dcs" | "cauchy" | "huber"; nullopt for anything else.
std::optional<RobustKernel> robustKernelFromString(const std::string& name);
const char* robustKernelName(RobustKernel kernel);

// Loop closures whose weight ends below this are reported as rejected (the convention).
constexpr double kRejectedWeight = 0.5;

// Default kernel width phi (chi2 units, g2o's e^T Omega e): wide enough for right loop closures
// with honest covariances (chi-square with 3 or 6 degrees of freedom: 99.5 % below 1.83 widths)
// and for the heavy tails of real data (largest right chi2 at the optimum of the shared datasets:
// manhattan 13.2, intel_g2o-vertigo 7.0, CSAIL 2.3, kitti_00 1.8; bench/robust_results.md); the
// adaptive width narrows it to the data (senders whose covariances are too large).
constexpr double kDefaultRobustWidth = 10.0;
// Default factor of the adaptive width over the 99th percentile of the accepted loop closures'
// chi2 (metrics.h adaptedRobustWidth).  Why 10: the largest right loop closure's chi2 lies up to
// 7.7 times above that percentile on the shared datasets (parking-garage; 2 or less elsewhere),
// wrong ones 100 to 1e5 times above the median.
constexpr double kDefaultAdaptiveWidthFactor = 10.0;

struct RobustOptions {
  RobustKernel kernel = RobustKernel::kNone;
  // phi, in g2o chi2 units (see the header comment); > 0.
  double width = kDefaultRobustWidth;
  // Once a solution is there, the width narrows to this multiple of the 99th percentile of the
  // accepted loop closures' chi2 when that is narrower (metrics.h adaptedRobustWidth) and the
  // solution is refined with it, so the kernel fits the real size of the residuals: a sender whose
  // covariances are 1e4 too large (parking-garage.g2o) makes wrong loop closures look plausible
  // to a fixed width.  0 keeps the width fixed.
  double adaptive_width_factor = kDefaultAdaptiveWidthFactor;
  bool enabled() const { return kernel != RobustKernel::kNone; }
  // Empty when valid, else what is wrong.
  std::string validate() const;
};

// w(chi2) in [0, 1]; 1 for kNone and for chi2 <= 0.
double robustWeight(const RobustOptions& options, double chi2);
// rho(chi2): the robust cost whose derivative is robustWeight; chi2 for kNone.
double robustCost(const RobustOptions& options, double chi2);

}  // namespace toro
