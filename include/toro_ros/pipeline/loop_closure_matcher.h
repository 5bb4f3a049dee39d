// Which keyframes a loop closure names: by id, or by stamps.  A stamp inside the trajectory attaches
// to the keyframe nearest in time, however far (the pipeline moves the measurement onto it with the
// odometry between the two); the tolerance only guards stamps before the first keyframe and in a
// gap of the trajectory (KeyframeRecord::after_gap).  Stamps later than the newest odometry wait in a bounded
// pending list.
#pragma once

#include <cstddef>
#include <deque>
#include <optional>
#include <string>
#include <vector>

#include <ros/time.h>

#include "toro_ros/LoopClosure.h"
#include "toro_ros/core/pose3.h"
#include "toro_ros/core/pose_graph.h"

namespace toro_ros {

// One keyframe as the pipeline remembers it, in id (= stamp) order.
struct KeyframeRecord {
  toro::NodeId id = 0;
  ros::Time stamp;
  toro::Pose3 odom_T_base;  // the odometry pose it was made from
  // The odometry between the keyframe before and this one was not seen (the first keyframe after a
  // loaded map: the node was down, or the odometry restarted with resume_link last_pose): nothing
  // is interpolated between the two.
  bool after_gap = false;
};

// Keyframes sorted by stamp and by id (both increase together).
class KeyframeIndex {
 public:
  void append(const KeyframeRecord& record) { records_.push_back(record); }
  void clear() { records_.clear(); }
  const std::vector<KeyframeRecord>& records() const { return records_; }
  std::size_t size() const { return records_.size(); }
  bool empty() const { return records_.empty(); }
  const KeyframeRecord& newest() const { return records_.back(); }

  // Nearest keyframe in time with |stamp - keyframe| <= tolerance (ties: the older one).
  std::optional<toro::NodeId> nearest(const ros::Time& stamp, double tolerance_sec) const;
  // |stamp - nearest keyframe| if one is within tolerance.
  std::optional<double> nearestDistance(const ros::Time& stamp, double tolerance_sec) const;
  // The keyframe a loop-closure stamp attaches to: between two keyframes with the odometry between
  // them seen, the nearer in time (ties: the older); after the newest, the newest; before the first
  // or in a gap (after_gap), the nearest within tolerance only.  nullopt otherwise.
  std::optional<toro::NodeId> attach(const ros::Time& stamp, double tolerance_sec) const;
  // odom_T_base at `stamp` interpolated (slerp) between the keyframes around it; nullopt before the
  // first, after the newest or in a gap.
  std::optional<toro::Pose3> odometryAt(const ros::Time& stamp) const;
  // The keyframe after / before `id` in stamp order, not across a gap, or nullopt.
  std::optional<toro::NodeId> next(toro::NodeId id) const;
  std::optional<toro::NodeId> previous(toro::NodeId id) const;
  // The record of an id, or nullptr.
  const KeyframeRecord* find(toro::NodeId id) const;

 private:
  std::vector<KeyframeRecord> records_;
};

struct LoopClosureMatchOptions {
  // Stamps before the first keyframe (or in a gap of the trajectory) attach to the nearest
  // keyframe only within this; a pending stamp waits at most this long for a nearer keyframe.
  double stamp_tolerance_sec = 0.25;
  std::size_t max_pending = 200;  // loop closures waiting for odometry to reach their stamps
  // Make a keyframe from the odometry sample at (or just after) a loop closure's stamp when no
  // keyframe is nearer.  Exact and quick, but keyframing then depends on when a loop closure
  // arrives relative to the odometry, so a live run and an offline replay of the same bag can
  // differ; false keeps keyframing a function of the odometry alone.
  bool create_keyframes = true;
  std::string validate() const;
};

// Refusal categories (counted by the pipeline; the log line gives the details).
namespace refusal {
constexpr const char* kInvalid = "invalid message";
constexpr const char* kUnknownId = "unknown node id";
constexpr const char* kNoKeyframe = "no keyframe within tolerance";
constexpr const char* kSameKeyframe = "both ends on one keyframe";
constexpr const char* kPendingFull = "pending list full";
constexpr const char* kReset = "dropped by reset";
constexpr const char* kGraph = "refused by the graph";
constexpr const char* kDuplicate = "duplicate message";
// Every axis of its covariance unmeasured (loop_closure_unmeasured_variance or more): it would be
// applied with ~0 information, moving nothing.
constexpr const char* kNothingMeasured = "no measured axis";
// Sent at or before the newest keyframe of a loaded map: already in it (a replay from the start).
constexpr const char* kBeforeResume = "before the resumed map";
}  // namespace refusal

struct MatchResult {
  enum class State { kMatched, kPending, kRefused } state = State::kRefused;
  toro::NodeId from = -1;
  toro::NodeId to = -1;
  std::string reason;  // refusal category
  std::string detail;  // the human-readable why
};

// True if an odometry sample at `candidate` (at or after `stamp`, within
// tolerance) is strictly nearer to `stamp` than every existing keyframe within tolerance.
bool betterKeyframe(const ros::Time& stamp, const ros::Time& candidate, const KeyframeIndex& index,
                    double tolerance_sec);

class LoopClosureMatcher {
 public:
  explicit LoopClosureMatcher(const LoopClosureMatchOptions& options) : options_(options) {}

  // Matches now, or queues the message if it names a stamp not yet decidable.  `newest_odometry`
  // is the stamp of the newest odometry message seen (zero if none).
  MatchResult submit(const LoopClosure& msg, const KeyframeIndex& index, const ros::Time& newest_odometry);

  // Pending loop closures that are now decidable, each with its result (never kPending).
  std::vector<std::pair<LoopClosure, MatchResult>> release(const KeyframeIndex& index,
                                                           const ros::Time& newest_odometry);

  // True if a pending loop closure names a stamp for which an odometry message at `stamp` would be
  // a better keyframe than any existing one (see betterKeyframe): the pipeline then makes one there.
  bool wantsKeyframeAt(const ros::Time& stamp, const KeyframeIndex& index) const;

  std::size_t pending() const { return pending_.size(); }
  // Empties the pending list, returning what was in it.
  std::vector<LoopClosure> clear();

 private:
  // A stamp is decidable once odometry has reached it and no later keyframe (stamped at or after
  // the newest odometry) could be nearer than the nearest existing one, or could be within
  // tolerance at all.
  bool decidable(const ros::Time& stamp, const KeyframeIndex& index, const ros::Time& newest_odometry) const;
  MatchResult matchNow(const LoopClosure& msg, const KeyframeIndex& index) const;

  LoopClosureMatchOptions options_;
  std::deque<LoopClosure> pending_;
};

}  // namespace toro_ros
