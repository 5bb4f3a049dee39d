#include "toro_ros/pipeline/odometry_history.h"

#include <algorithm>

namespace toro_ros {

namespace {

template <class Container, class Sample>
void bracket(const Container& samples, const ros::Time& stamp, const Sample** lower, const Sample** upper) {
  if (samples.empty()) return;
  const auto after = std::upper_bound(samples.begin(), samples.end(), stamp,
                                      [](const ros::Time& t, const Sample& s) { return t < s.stamp; });
  if (after != samples.begin()) *lower = &*(after - 1);
  if (after != samples.end() && *upper == nullptr) *upper = &*after;
}

toro::Pose3 interpolate(const ros::Time& a_stamp, const toro::Pose3& a, const ros::Time& b_stamp,
                        const toro::Pose3& b, const ros::Time& stamp) {
  const double fraction = (stamp - a_stamp).toSec() / (b_stamp - a_stamp).toSec();
  return toro::slerp(a, b, fraction);
}

}  // namespace

void OdometryHistory::add(const ros::Time& stamp, const toro::Pose3& odom_T_base) {
  if (span_sec_ <= 0) return;
  recent_.push_back(Sample{stamp, odom_T_base});
  while (!recent_.empty() && (stamp - recent_.front().stamp).toSec() > span_sec_) {
    retire(recent_.front());
    recent_.pop_front();
  }
}

void OdometryHistory::retire(const Sample& sample) {
  if (trace_.empty()) {
    trace_.push_back(sample);  // the first message of the run is always kept
    return;
  }
  if (pending_) {
    // The pending message may be dropped if the trace's last kept message and this one put it,
    // and every message dropped since, where they were; else it is kept.
    const Sample& kept = trace_.back();
    auto fits = [&](const Sample& s) {
      const toro::Pose3 guess =
          interpolate(kept.stamp, kept.odom_T_base, sample.stamp, sample.odom_T_base, s.stamp);
      const toro::Pose3 error = toro::relativePose(guess, s.odom_T_base);
      return error.translation().norm() <= kTraceTolerance.translation_m &&
             error.angle() <= kTraceTolerance.rotation_rad;
    };
    const bool drop = dropped_.size() < kMaxDropped && fits(*pending_) &&
                      std::all_of(dropped_.begin(), dropped_.end(), fits);
    if (drop) {
      dropped_.push_back(*pending_);
    } else {
      trace_.push_back(*pending_);
      dropped_.clear();
    }
  }
  pending_ = sample;
}

std::optional<toro::Pose3> OdometryHistory::at(const ros::Time& stamp) const {
  // Three runs in stamp order: the trace, the pending message, the full-rate span.
  const Sample* lower = nullptr;
  const Sample* upper = nullptr;
  bracket(trace_, stamp, &lower, &upper);
  if (pending_) {
    if (pending_->stamp <= stamp)
      lower = &*pending_;
    else if (upper == nullptr)
      upper = &*pending_;
  }
  bracket(recent_, stamp, &lower, &upper);
  if (lower == nullptr) return std::nullopt;
  if (lower->stamp == stamp) return lower->odom_T_base;
  if (upper == nullptr) return std::nullopt;
  return interpolate(lower->stamp, lower->odom_T_base, upper->stamp, upper->odom_T_base, stamp);
}

void OdometryHistory::clear() {
  trace_.clear();
  dropped_.clear();
  pending_.reset();
  recent_.clear();
}

}  // namespace toro_ros
