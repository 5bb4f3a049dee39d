// The newest chi2 values of one kind of consistency test (a ring) and their low quantile: the
// scale a support threshold reads the sender's covariances by (MapOptimizer's pair and path
// tests).  The quantile is kept until the next value arrives, because the tests ask for it once
// per candidate and the values change only once per loop closure.
#pragma once

#include <algorithm>
#include <cstddef>
#include <limits>
#include <vector>

namespace toro_ros {

class RecentChi2 {
 public:
  RecentChi2(std::size_t capacity, double quantile) : capacity_(capacity), quantile_(quantile) {}

  void add(double chi2) {
    if (values_.size() < capacity_) values_.push_back(chi2);
    else values_[added_ % capacity_] = chi2;
    ++added_;
    cached_ = false;
  }
  void clear() {
    values_.clear();
    added_ = 0;
    cached_ = false;
  }
  // Values ever added (the ring keeps the newest `capacity` of them).
  std::size_t count() const { return added_; }
  // The quantile (the constructor's fraction) of the values kept; NaN when there are none.
  double lowQuantile() const {
    if (values_.empty()) return std::numeric_limits<double>::quiet_NaN();
    if (!cached_) {
      scratch_ = values_;
      const auto at = scratch_.begin() + static_cast<std::ptrdiff_t>(scratch_.size() * quantile_);
      std::nth_element(scratch_.begin(), at, scratch_.end());
      low_ = *at;
      cached_ = true;
    }
    return low_;
  }

 private:
  std::size_t capacity_;
  double quantile_;
  std::vector<double> values_;
  std::size_t added_ = 0;
  mutable std::vector<double> scratch_;
  mutable double low_ = 0.0;
  mutable bool cached_ = false;
};

}  // namespace toro_ros
