#include "toro_ros/pipeline/pipeline.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>

#include <ros/serialization.h>

#include "toro_ros/core/carried_measurement.h"
#include "toro_ros/core/chi_square.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/sparse_finisher.h"
#include "toro_ros/pipeline/msg_conversion.h"

namespace toro_ros {

namespace {

KeyframerOptions keyframerOptions(const PipelineOptions& o) {
  KeyframerOptions out = o.keyframer;
  out.planar = o.planar;
  return out;
}

std::string describe(const LoopClosure& msg) {
  if (msg.id_from >= 0 && msg.id_to >= 0)
    return "loop closure " + std::to_string(msg.id_from) + " -> " + std::to_string(msg.id_to);
  return "loop closure " + stampString(msg.stamp_from) + " -> " + stampString(msg.stamp_to);
}

// FNV-1a over the serialised message: equal for resent copies of one message (a 64-bit
// collision between two different loop closures is not a practical concern).
std::uint64_t messageHash(const LoopClosure& msg) {
  const std::uint32_t size = ros::serialization::serializationLength(msg);
  std::vector<std::uint8_t> buffer(size);
  ros::serialization::OStream stream(buffer.data(), size);
  ros::serialization::serialize(stream, msg);
  std::uint64_t h = 1469598103934665603ull;
  for (std::uint8_t b : buffer) h = (h ^ b) * 1099511628211ull;
  return h;
}

// The options, or std::invalid_argument saying what is wrong with them.
const PipelineOptions& validated(const PipelineOptions& options) {
  const std::string error = options.validate();
  if (!error.empty()) throw std::invalid_argument("invalid pipeline options: " + error);
  return options;
}

// tf2 ignores a leading slash ("/odom" is "odom").
std::string withoutLeadingSlash(const std::string& frame) {
  return !frame.empty() && frame[0] == '/' ? frame.substr(1) : frame;
}

}  // namespace

std::string toString(toro::RobustKernel kernel) { return toro::robustKernelName(kernel); }

std::string PipelineOptions::validate() const {
  for (const std::string& e : {keyframer.validate(), matcher.validate(),
                               loop_closure_default_stddev.validate(), optimization.validate()})
    if (!e.empty()) return e;
  if (!(std::isfinite(time_jump_reset_sec) && time_jump_reset_sec >= 0))
    return "time_jump_reset_sec must be >= 0";
  if (!(std::isfinite(odometry_history_sec) && odometry_history_sec >= 0))
    return "odometry_history_sec must be >= 0";
  if (!(loop_closure_gate_confidence >= 0 && loop_closure_gate_confidence < 1))
    return "loop_closure_gate_confidence must be in [0, 1) (0 disables the gate)";
  if (!(std::isfinite(loop_closure_gate_variance_factor) && loop_closure_gate_variance_factor > 0))
    return "loop_closure_gate_variance_factor must be > 0";
  const std::string robust_problem = robust.validate();
  if (!robust_problem.empty()) return robust_problem;
  return persistence.validate();
}

Pipeline::Pipeline(const PipelineOptions& options, WarningSink warn, InfoSink info)
    : options_(validated(options)),
      warn_(std::move(warn)),
      info_(std::move(info)),
      map_(
          options.optimization, options.robust, options.planar, gateOptionsOf(options), &counters_,
          [this](const std::string& category, const std::string& detail) { refuse(category, detail); },
          [this](const std::string& note) {
            if (warn_) warn_(note);
          }),
      keyframer_(keyframerOptions(options)),
      matcher_(options.matcher),
      odometry_history_(options.odometry_history_sec) {}

GateOptions Pipeline::gateOptionsOf(const PipelineOptions& options) {
  return GateOptions{options.loop_closure_gate_confidence, options.loop_closure_gate_variance_factor};
}

void Pipeline::refuse(const std::string& category, const std::string& detail) {
  ++revision_;
  const std::uint64_t n = ++counters_.refused_by_reason[category];
  // A misconfigured sender repeats the same refusal at its message rate: log occurrences 1, 2, 4,
  // 8, ... of each category (the counters have every one), so the log stays readable and bounded
  // without reading any clock.
  if (!warn_ || (n & (n - 1)) != 0) return;
  warn_(n == 1 ? category + ": " + detail
               : category + ": " + detail + " (occurrence " + std::to_string(n) +
                     " of this kind; only powers of two are logged)");
}

void Pipeline::refuseLoopClosure(const MatchResult& match, const LoopClosure& msg) {
  ++counters_.loop_closures_refused;
  refuse("loop closure: " + match.reason, describe(msg) + " refused: " + match.detail);
}

void Pipeline::handleOdometry(const nav_msgs::Odometry& msg) {
  ++counters_.odometry_messages;
  const std::string invalid = validateOdometry(msg);
  const ros::Time stamp = msg.header.stamp;
  if (!invalid.empty()) {
    ++counters_.odometry_refused;
    refuse("odometry: invalid message", "odometry at " + stampString(stamp) + " refused: " + invalid);
    return;
  }
  if (!options_.odom_frame.empty() && !msg.header.frame_id.empty() &&
      withoutLeadingSlash(msg.header.frame_id) != withoutLeadingSlash(options_.odom_frame)) {
    ++counters_.odometry_refused;
    refuse("odometry: wrong frame", "odometry at " + stampString(stamp) + " is in frame '" +
                                        msg.header.frame_id + "', odom_frame is '" + options_.odom_frame +
                                        "'");
    return;
  }
  const OdometrySample sample{stamp,
                              options_.planar ? planarPoseFromMsg(msg.pose.pose) : poseFromMsg(msg.pose.pose),
                              covarianceMatrix(msg.pose.covariance)};
  if (resume_after_ && !resumeWith(sample)) return;
  if (!newest_odometry_.isZero() && stamp <= newest_odometry_) {
    const double back = (newest_odometry_ - stamp).toSec();
    if (back > options_.time_jump_reset_sec) {
      ++counters_.time_jump_resets;
      reset("odometry stamp " + stampString(stamp) + " is " + std::to_string(back) +
            " s before the newest (" + stampString(newest_odometry_) +
            "): time jumped back (bag restarted?), graph reset");
    } else {
      ++counters_.odometry_refused;
      refuse("odometry: out of order", "odometry at " + stampString(stamp) + " is not after the newest " +
                                           stampString(newest_odometry_));
      return;
    }
  }
  newest_odometry_ = stamp;
  odometry_quiet_sec_ = 0.0;
  last_odometry_ = sample;
  keyframer_.observe(sample);
  odometry_history_.add(stamp, last_odometry_->odom_T_base);
  if (keyframer_.isKeyframe(*last_odometry_) ||
      (options_.matcher.create_keyframes && matcher_.wantsKeyframeAt(stamp, keyframes_)))
    addKeyframe(*last_odometry_);
  releasePending();
  autosaveIfDue(stamp);
}

void Pipeline::addKeyframe(const OdometrySample& sample) {
  // After a load the reference keyframe's covariance is unknown (NaN): defaults, not a refusal.
  const bool reference_known = !keyframer_.last() || keyframer_.last()->covariance.allFinite();
  const std::optional<OdometryStep> step = keyframer_.accept(sample);
  if (step && reference_known) countOdometryStep(step->information);
  appendKeyframe(sample, step);
}

void Pipeline::appendKeyframe(const OdometrySample& sample, const std::optional<OdometryStep>& step) {
  const toro::NodeId id = next_id_++;
  // A new keyframe continues from the corrected previous one, so the odometry constraint starts
  // with zero residual and the correction made so far carries over.
  const toro::Pose3 pose =
      step ? map_.graph().pose(keyframes_.newest().id) * step->previous_T_current : sample.odom_T_base;
  std::optional<toro::Constraint> odometry;
  if (step)
    odometry = toro::Constraint{keyframes_.newest().id, id, step->previous_T_current,
                                step->information.information, toro::ConstraintKind::kOdometry};
  map_.addKeyframe(id, pose, sample.stamp, odometry);
  ++revision_;
  keyframes_.append(KeyframeRecord{id, sample.stamp, sample.odom_T_base, next_keyframe_after_gap_});
  next_keyframe_after_gap_ = false;
}

void Pipeline::keyframeForStamps(const LoopClosure& msg) {
  if (!options_.matcher.create_keyframes || (msg.id_from >= 0 && msg.id_to >= 0)) return;
  if (!last_odometry_ || (!keyframes_.empty() && keyframes_.newest().stamp >= last_odometry_->stamp)) return;
  for (const ros::Time& s : {msg.stamp_from, msg.stamp_to}) {
    // A loop closure about "now" (the usual case for a place recogniser) should not wait for the
    // next odometry message: the newest odometry sample becomes the keyframe it names.
    if (betterKeyframe(s, last_odometry_->stamp, keyframes_, options_.matcher.stamp_tolerance_sec)) {
      addKeyframe(*last_odometry_);
      return;
    }
  }
}

void Pipeline::handleLoopClosure(const LoopClosure& msg) {
  ++counters_.loop_closures_received;
  if (!loaded_until_.isZero() && !msg.header.stamp.isZero() && msg.header.stamp <= loaded_until_) {
    MatchResult r;
    r.reason = refusal::kBeforeResume;
    r.detail = "sent at " + stampString(msg.header.stamp) + ", not after the newest loaded keyframe " +
               stampString(loaded_until_) + " (it is in the map already)";
    refuseLoopClosure(r, msg);
    return;
  }
  keyframeForStamps(msg);
  const MatchResult r = matcher_.submit(msg, keyframes_, newest_odometry_);
  if (r.state == MatchResult::State::kMatched)
    applyLoopClosure(msg, r);
  else if (r.state == MatchResult::State::kRefused)
    refuseLoopClosure(r, msg);
}

void Pipeline::applyLoopClosure(const LoopClosure& msg, const MatchResult& match) {
  const toro::Matrix6 covariance = covarianceMatrix(msg.covariance);
  const InformationResult info = informationFromCovariance(
      options_.planar ? planarCovariance(covariance) : covariance, options_.loop_closure_default_stddev,
      options_.loop_closure_unmeasured_variance);
  if (std::all_of(info.axes.begin(), info.axes.end(),
                  [](AxisReading a) { return a == AxisReading::kUnmeasured; })) {
    MatchResult refused = match;
    refused.reason = refusal::kNothingMeasured;
    refused.detail = "every variance is at least loop_closure_unmeasured_variance (" +
                     std::to_string(options_.loop_closure_unmeasured_variance) + "): it constrains nothing";
    refuseLoopClosure(refused, msg);
    return;
  }
  // The same message twice (a bridge or recogniser that resends) would count one measurement
  // twice; two different measurements of the same pair are independent and both kept.
  if (!applied_messages_.insert(messageHash(msg)).second) {
    MatchResult refused = match;
    refused.reason = refusal::kDuplicate;
    refused.detail = "the same message (stamps, ids, pose, covariance) was applied before";
    refuseLoopClosure(refused, msg);
    return;
  }
  toro::Pose3 measurement = options_.planar ? planarPoseFromMsg(msg.from_T_to) : poseFromMsg(msg.from_T_to);
  toro::Matrix6 information = info.information;
  if (msg.id_from < 0 || msg.id_to < 0) {
    // The message measures stamp_from_T_stamp_to; the constraint joins the matched keyframes, the
    // odometry between each stamp and its keyframe carrying it there, with that odometry's
    // uncertainty (a scan's stamp half a keyframe step from its keyframe: decimetres of wheel
    // odometry beside a millimetre-sure scan match).
    const toro::Pose3 from_T_stamp = keyframeToStamp(match.from, msg.stamp_from);
    const toro::Pose3 to_T_stamp = keyframeToStamp(match.to, msg.stamp_to);
    const toro::Matrix6 from_covariance = keyframeToStampCovariance(match.from, msg.stamp_from, from_T_stamp);
    const toro::Matrix6 to_covariance = keyframeToStampCovariance(match.to, msg.stamp_to, to_T_stamp);
    if (!from_covariance.isZero() || !to_covariance.isZero())
      information = toro::angleToQuaternionUnits(
          toro::carriedInformation(from_covariance, measurement, toro::quaternionToAngleUnits(information),
                                   to_T_stamp, to_covariance));
    measurement = from_T_stamp * measurement * to_T_stamp.inverse();
  }
  const toro::Constraint c{match.from, match.to, measurement, information,
                           toro::ConstraintKind::kLoopClosure};
  const std::string objection = map_.addLoopClosure(c, msg.header.stamp);
  if (!objection.empty()) {
    MatchResult refused = match;
    refused.reason = refusal::kGraph;
    refused.detail = objection;
    refuseLoopClosure(refused, msg);
    return;
  }
  countLoopClosureInformation(info);
  ++revision_;
}

void Pipeline::releasePending() {
  if (matcher_.pending() == 0) return;
  for (const auto& [msg, r] : matcher_.release(keyframes_, newest_odometry_)) {
    if (r.state == MatchResult::State::kMatched)
      applyLoopClosure(msg, r);
    else
      refuseLoopClosure(r, msg);
  }
}

bool Pipeline::hasScheduledWork() const { return !paused_ && map_.hasScheduledWork(); }

ros::Time Pipeline::scheduleClock() const {
  if (newest_odometry_.isZero() || odometry_quiet_sec_ <= 0.0) return newest_odometry_;
  return newest_odometry_ + ros::Duration(odometry_quiet_sec_);
}

bool Pipeline::runScheduledOptimization() { return !paused_ && map_.runScheduledStep(scheduleClock()); }

std::optional<FinishJob> Pipeline::takeFinishJob() {
  if (paused_) return std::nullopt;
  return map_.takeFinishJob(scheduleClock());
}

bool Pipeline::mergeFinish(const FinishOutcome& outcome) {
  const bool merged = map_.mergeFinish(outcome);
  // A finish dropped because the graph was reset meanwhile is routine; one that failed is not.
  if (!outcome.success && outcome.error != "cancelled" && warn_) warn_("background finish: " + outcome.error);
  return merged;
}

OptimizeResult Pipeline::optimize(unsigned iterations, const std::string& mode) {
  OptimizeResult r;
  if (mode != "full" && mode != "finish" && !mode.empty()) {
    r.message = "unknown mode '" + mode + "' (use \"full\" or \"finish\")";
    return r;
  }
  if (map_.graph().numConstraints() == 0) {
    r.message = "nothing to optimise: the graph has no constraints";
    return r;
  }
  return map_.optimize(iterations, mode == "finish");
}

void Pipeline::clearGraph() {
  for (const LoopClosure& msg : matcher_.clear()) {
    MatchResult r;
    r.reason = refusal::kReset;
    r.detail = "the graph was reset while it waited";
    refuseLoopClosure(r, msg);
  }
  map_.clear();
  keyframer_.reset();
  logged_odometry_rule_.clear();
  last_odometry_.reset();
  odometry_history_.clear();
  keyframes_.clear();
  newest_odometry_ = ros::Time();
  next_id_ = 0;
  applied_messages_.clear();
  resume_after_.reset();
  next_keyframe_after_gap_ = false;
  loaded_until_ = ros::Time();
  ++counters_.resets;
  ++epoch_;
  ++revision_;
}

void Pipeline::reset(const std::string& why) {
  if (warn_) warn_("reset: " + why);
  clearGraph();
}

std::shared_ptr<const Snapshot> Pipeline::makeSnapshot() {
  auto s = std::make_shared<Snapshot>();
  s->generation = ++generation_;
  s->epoch = epoch_;
  const toro::PoseGraph& g = map_.graph();
  const auto& records = keyframes_.records();
  map_.updateSnapshot(snapshot_builder_, records);
  s->keyframes = snapshot_builder_.shareKeyframes();
  s->edges = snapshot_builder_.shareEdges();
  s->down_weighted_loop_closures = snapshot_builder_.downWeighted();
  s->robust_width = map_.robustWidth();
  for (const RejectedLoopClosure& r : map_.rejected())
    if (g.hasNode(r.constraint.from) && g.hasNode(r.constraint.to))
      s->rejected_edges.push_back(
          SnapshotEdge{g.indexOf(r.constraint.from), g.indexOf(r.constraint.to), true, r.chi2});
  if (!records.empty()) {
    s->has_map_T_odom = true;
    s->map_T_odom = g.node(records.size() - 1).pose * records.back().odom_T_base.inverse();
    s->newest_stamp = records.back().stamp;
  }
  s->chi2 = map_.lastChi2();
  s->last_optimization_sec = map_.lastOptimizationSec();
  s->pending_loop_closures = matcher_.pending();
  s->counters = counters_;
  s->last_finish = map_.lastFinish();
  s->finish_running = map_.finishOutstanding();
  s->finish_off_reason = map_.finishOffReason();
  return s;
}

PipelineStatus Pipeline::status() const {
  PipelineStatus s;
  s.keyframes = keyframes_.size();
  s.constraints = map_.graph().numConstraints();
  s.pending_loop_closures = matcher_.pending();
  s.last_chi2 = map_.lastChi2();
  s.last_optimization_sec = map_.lastOptimizationSec();
  s.paused = paused_;
  s.counters = counters_;
  s.rejected = map_.rejected();
  s.odometry_covariance_rule = keyframer_.ruleDescription();
  s.loop_closure_covariance_rule = loop_closure_rule_;
  s.down_weighted = map_.downWeighted();
  s.robust_width = map_.robustWidth();
  s.last_finish = map_.lastFinish();
  s.finish_running = map_.finishOutstanding();
  s.finish_off_reason = map_.finishOffReason();
  return s;
}

}  // namespace toro_ros
