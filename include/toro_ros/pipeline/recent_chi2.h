// The newest chi2 values of one kind of consistency test (a ring) and their low quantile: the
// scale a support threshold reads the sender's covariances by (MapOptimizer's pair and path
// tests).  The quantile is kept until the next value arrives, because the tests ask for it once
// per candidate and the values change only once per loop closure.  A test whose cycle closes to
// rounding is counted but is no sample of the scale (see add).
#pragma once

#include <algorithm>
#include <cstddef>
#include <limits>
#include <vector>

namespace toro_ros {

class RecentChi2 {
 public:
  RecentChi2(std::size_t capacity, double quantile) : capacity_(capacity), quantile_(quantile) {}

  // Below this a cycle closed to rounding (noise-free loop closures: a simulator's, a test's exact
  // ones give 1e-25 to 1e-31; the most precise real sender measured here, parking-garage, 1e-8),
  // which says nothing about how large the sender's covariances are: such values are counted but
  // not kept.  Kept, a fifth of them narrowed the pair threshold to 3e-29 and the path veto to its
  // floor, so every real pair failed and right loop closures were held (bench_node_latency's
  // exact loop closures: half of the revisits never moved the map).
  static constexpr double kClosedToRounding = 1e-16;

  void add(double chi2) {
    ++added_;
    if (!(chi2 > kClosedToRounding)) return;
    if (values_.size() < capacity_) values_.push_back(chi2);
    else values_[kept_ % capacity_] = chi2;
    ++kept_;
    cached_ = false;
  }
  void clear() {
    values_.clear();
    added_ = kept_ = 0;
    cached_ = false;
  }
  // Values ever added, closed to rounding or not.
  std::size_t count() const { return added_; }
  // Values kept as samples of the scale (at most `capacity`: the newest).
  std::size_t samples() const { return values_.size(); }
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
  std::size_t kept_ = 0;
  mutable std::vector<double> scratch_;
  mutable double low_ = 0.0;
  mutable bool cached_ = false;
};

}  // namespace toro_ros
