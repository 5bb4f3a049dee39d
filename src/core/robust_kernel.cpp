#include "toro_ros/core/robust_kernel.h"

#include <algorithm>
#include <cmath>

namespace toro {

std::optional<RobustKernel> robustKernelFromString(const std::string& name) {
  for (RobustKernel k : {RobustKernel::kNone, RobustKernel::kDcs, RobustKernel::kCauchy, RobustKernel::kHuber})
    if (name == robustKernelName(k)) return k;
  return std::nullopt;
}

const char* robustKernelName(RobustKernel kernel) {
  switch (kernel) {
    case RobustKernel::kNone:
      return "none";
    case RobustKernel::kDcs:
      return "dcs";
    case RobustKernel::kCauchy:
      return "cauchy";
    case RobustKernel::kHuber:
      return "huber";
  }
  return "unknown";
}

std::string RobustOptions::validate() const {
  if (!(std::isfinite(width) && width > 0)) return "robust kernel width must be a positive finite number";
  if (!(std::isfinite(adaptive_width_factor) && adaptive_width_factor >= 0))
    return "robust adaptive width factor must be a finite number >= 0 (0: fixed width)";
  return {};
}

double robustWeight(const RobustOptions& options, double chi2) {
  const double phi = options.width;
  if (!(chi2 > 0.0)) return 1.0;
  if (!std::isfinite(chi2)) return options.kernel == RobustKernel::kNone ? 1.0 : 0.0;
  switch (options.kernel) {
    case RobustKernel::kNone:
      return 1.0;
    case RobustKernel::kDcs: {
      const double s = 2.0 * phi / (phi + chi2);
      return s >= 1.0 ? 1.0 : s * s;
    }
    case RobustKernel::kCauchy:
      return 1.0 / (1.0 + chi2 / phi);
    case RobustKernel::kHuber:
      return chi2 <= phi ? 1.0 : std::sqrt(phi / chi2);
  }
  return 1.0;
}

double robustCost(const RobustOptions& options, double chi2) {
  const double phi = options.width;
  if (!(chi2 > 0.0)) return 0.0;
  switch (options.kernel) {
    case RobustKernel::kNone:
      return chi2;
    case RobustKernel::kDcs:
      // The integral of the weight: chi2 up to phi (s >= 1 there), then continuous and bounded by 3 phi.
      if (!std::isfinite(chi2)) return 3.0 * phi;
      return chi2 <= phi ? chi2 : 3.0 * phi - 4.0 * phi * phi / (phi + chi2);
    case RobustKernel::kCauchy:
      return phi * std::log1p(chi2 / phi);
    case RobustKernel::kHuber:
      return chi2 <= phi ? chi2 : 2.0 * std::sqrt(phi * chi2) - phi;
  }
  return chi2;
}

}  // namespace toro
