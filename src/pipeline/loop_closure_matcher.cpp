#include "toro_ros/pipeline/loop_closure_matcher.h"

#include <algorithm>
#include <cmath>

#include "toro_ros/pipeline/msg_conversion.h"

namespace toro_ros {

namespace {

bool byId(const LoopClosure& msg) { return msg.id_from >= 0 && msg.id_to >= 0; }

ros::Time latestStamp(const LoopClosure& msg) { return std::max(msg.stamp_from, msg.stamp_to); }

MatchResult refused(const char* reason, const std::string& detail) {
  MatchResult r;
  r.state = MatchResult::State::kRefused;
  r.reason = reason;
  r.detail = detail;
  return r;
}

}  // namespace

std::optional<toro::NodeId> KeyframeIndex::nearest(const ros::Time& stamp, double tolerance_sec) const {
  if (records_.empty()) return std::nullopt;
  auto it = std::lower_bound(records_.begin(), records_.end(), stamp,
                             [](const KeyframeRecord& r, const ros::Time& t) { return r.stamp < t; });
  const KeyframeRecord* best = nullptr;
  double best_dt = 0.0;
  auto consider = [&](const KeyframeRecord& r) {
    const double dt = std::abs((r.stamp - stamp).toSec());
    if (best == nullptr || dt < best_dt) {
      best = &r;
      best_dt = dt;
    }
  };
  if (it != records_.begin()) consider(*(it - 1));
  if (it != records_.end()) consider(*it);
  if (best == nullptr || best_dt > tolerance_sec) return std::nullopt;
  return best->id;
}

std::optional<toro::NodeId> KeyframeIndex::attach(const ros::Time& stamp, double tolerance_sec) const {
  if (records_.empty()) return std::nullopt;
  const auto after =
      std::lower_bound(records_.begin(), records_.end(), stamp,
                       [](const KeyframeRecord& r, const ros::Time& t) { return r.stamp < t; });
  if (after == records_.end()) return records_.back().id;
  if (after == records_.begin() || after->stamp == stamp || after->after_gap)
    return nearest(stamp, tolerance_sec);
  const KeyframeRecord& before = *(after - 1);
  return (stamp - before.stamp) <= (after->stamp - stamp) ? before.id : after->id;
}

std::optional<toro::Pose3> KeyframeIndex::odometryAt(const ros::Time& stamp) const {
  if (records_.empty() || stamp < records_.front().stamp || stamp > records_.back().stamp)
    return std::nullopt;
  const auto after =
      std::lower_bound(records_.begin(), records_.end(), stamp,
                       [](const KeyframeRecord& r, const ros::Time& t) { return r.stamp < t; });
  if (after->stamp == stamp) return after->odom_T_base;
  if (after->after_gap) return std::nullopt;
  const KeyframeRecord& before = *(after - 1);
  const double fraction = (stamp - before.stamp).toSec() / (after->stamp - before.stamp).toSec();
  return toro::slerp(before.odom_T_base, after->odom_T_base, fraction);
}

std::optional<toro::NodeId> KeyframeIndex::next(toro::NodeId id) const {
  const KeyframeRecord* r = find(id);
  if (r == nullptr || r == &records_.back() || (r + 1)->after_gap) return std::nullopt;
  return (r + 1)->id;
}

std::optional<toro::NodeId> KeyframeIndex::previous(toro::NodeId id) const {
  const KeyframeRecord* r = find(id);
  if (r == nullptr || r == &records_.front() || r->after_gap) return std::nullopt;
  return (r - 1)->id;
}

std::optional<double> KeyframeIndex::nearestDistance(const ros::Time& stamp, double tolerance_sec) const {
  const auto id = nearest(stamp, tolerance_sec);
  if (!id) return std::nullopt;
  return std::abs((find(*id)->stamp - stamp).toSec());
}

const KeyframeRecord* KeyframeIndex::find(toro::NodeId id) const {
  auto it = std::lower_bound(records_.begin(), records_.end(), id,
                             [](const KeyframeRecord& r, toro::NodeId i) { return r.id < i; });
  return (it != records_.end() && it->id == id) ? &*it : nullptr;
}

std::string LoopClosureMatchOptions::validate() const {
  if (!(std::isfinite(stamp_tolerance_sec) && stamp_tolerance_sec >= 0))
    return "loop closure stamp_tolerance_sec must be >= 0";
  if (max_pending == 0) return "loop closure max_pending must be > 0";
  return "";
}

bool LoopClosureMatcher::decidable(const ros::Time& stamp, const KeyframeIndex& index,
                                   const ros::Time& newest_odometry) const {
  if (newest_odometry.isZero() || stamp > newest_odometry) return false;
  // Every later keyframe has a stamp >= the newest odometry, so it is at least `ahead` away.
  const double ahead = (newest_odometry - stamp).toSec();
  if (ahead > options_.stamp_tolerance_sec) return true;
  const auto distance = index.nearestDistance(stamp, options_.stamp_tolerance_sec);
  return distance && *distance <= ahead;
}

MatchResult LoopClosureMatcher::matchNow(const LoopClosure& msg, const KeyframeIndex& index) const {
  MatchResult r;
  if (byId(msg)) {
    for (toro::NodeId id : {msg.id_from, msg.id_to})
      if (index.find(id) == nullptr)
        return refused(refusal::kUnknownId, "no keyframe has id " + std::to_string(id));
    r.from = msg.id_from;
    r.to = msg.id_to;
  } else {
    auto from = index.attach(msg.stamp_from, options_.stamp_tolerance_sec);
    auto to = index.attach(msg.stamp_to, options_.stamp_tolerance_sec);
    for (const auto& [id, stamp] : {std::pair{from, msg.stamp_from}, std::pair{to, msg.stamp_to}})
      if (!id)
        return refused(refusal::kNoKeyframe,
                       "stamp " + stampString(stamp) +
                           " is before the first keyframe or in a gap of the "
                           "trajectory (before a resumed map's new odometry), and no keyframe is within " +
                           std::to_string(options_.stamp_tolerance_sec) + " s of it");
    if (*from == *to) {
      // Two stamps nearest to one keyframe: the later end moves on to the next keyframe (or the
      // earlier one back to the previous), the odometry between carries the measurement there.
      const bool to_is_later = msg.stamp_to > msg.stamp_from;
      if (const auto n = index.next(*from)) {
        (to_is_later ? to : from) = n;
      } else if (const auto p = index.previous(*from)) {
        (to_is_later ? from : to) = p;
      } else {
        return refused(refusal::kSameKeyframe, "stamps " + stampString(msg.stamp_from) + " and " +
                                                   stampString(msg.stamp_to) + " both match keyframe " +
                                                   std::to_string(*from) + ", the only one of its run");
      }
    }
    r.from = *from;
    r.to = *to;
  }
  r.state = MatchResult::State::kMatched;
  return r;
}

MatchResult LoopClosureMatcher::submit(const LoopClosure& msg, const KeyframeIndex& index,
                                       const ros::Time& newest_odometry) {
  const std::string invalid = validateLoopClosure(msg);
  if (!invalid.empty()) return refused(refusal::kInvalid, invalid);
  if (byId(msg) || decidable(latestStamp(msg), index, newest_odometry)) return matchNow(msg, index);
  if (pending_.size() >= options_.max_pending)
    return refused(refusal::kPendingFull, "already " + std::to_string(pending_.size()) +
                                              " loop closures wait for odometry to reach their stamps");
  pending_.push_back(msg);
  MatchResult r;
  r.state = MatchResult::State::kPending;
  return r;
}

std::vector<std::pair<LoopClosure, MatchResult>> LoopClosureMatcher::release(
    const KeyframeIndex& index, const ros::Time& newest_odometry) {
  std::vector<std::pair<LoopClosure, MatchResult>> out;
  // Keep arrival order among the released ones so results do not depend on the list's layout.
  std::deque<LoopClosure> still;
  for (const LoopClosure& msg : pending_) {
    if (decidable(latestStamp(msg), index, newest_odometry))
      out.emplace_back(msg, matchNow(msg, index));
    else
      still.push_back(msg);
  }
  pending_.swap(still);
  return out;
}

bool LoopClosureMatcher::wantsKeyframeAt(const ros::Time& stamp, const KeyframeIndex& index) const {
  for (const LoopClosure& msg : pending_)
    for (const ros::Time& s : {msg.stamp_from, msg.stamp_to})
      if (betterKeyframe(s, stamp, index, options_.stamp_tolerance_sec)) return true;
  return false;
}

bool betterKeyframe(const ros::Time& stamp, const ros::Time& candidate, const KeyframeIndex& index,
                    double tolerance_sec) {
  if (stamp > candidate) return false;
  const double d = (candidate - stamp).toSec();
  if (d > tolerance_sec) return false;
  const auto existing = index.nearestDistance(stamp, tolerance_sec);
  return !existing || d < *existing;
}

std::vector<LoopClosure> LoopClosureMatcher::clear() {
  std::vector<LoopClosure> out(pending_.begin(), pending_.end());
  pending_.clear();
  return out;
}

}  // namespace toro_ros
