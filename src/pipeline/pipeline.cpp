#include "toro_ros/pipeline/pipeline.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>

#include <ros/serialization.h>

#include "toro_ros/core/chi_square.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/sparse_finisher.h"
#include "toro_ros/pipeline/msg_conversion.h"

namespace toro_ros {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr int kMaxRecheckRounds = 10;
// The robust width adapts once this many accepted loop closures give it a median, after every loop
// closure while fewer than kEarlyLoopClosures were applied (senders whose covariances are far too
// large must be caught before wrong loop closures bend the map), then after full rounds.
constexpr std::size_t kMinLoopClosuresToAdaptWidth = 5;
constexpr std::size_t kEarlyLoopClosures = 200;
// The width narrows to this many times the median arrival innovation of the accepted loop closures:
// right ones' residuals are heavy-tailed (largest / median up to ~200 on real data), wrong ones lie
// 100 to 1e5 times above the median.
constexpr double kMedianWidthFactor = 250.0;

// Seconds of wall time spent in `f`; reported only, never used to decide anything.
template <class F>
double timed(F&& f) {
  const auto t0 = std::chrono::steady_clock::now();
  f();
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

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

// tf2 ignores a leading slash ("/odom" is "odom").
std::string withoutLeadingSlash(const std::string& frame) {
  return !frame.empty() && frame[0] == '/' ? frame.substr(1) : frame;
}

}  // namespace

std::string toString(toro::RobustKernel kernel) { return toro::robustKernelName(kernel); }

std::string OptimizationOptions::validate() const {
  if (!(std::isfinite(gamma) && gamma > 0)) return "optimization gamma must be > 0";
  if (full_iterations < 0) return "optimization full_iterations must be >= 0";
  if (full_every_keyframes < 0) return "optimization full_every_keyframes must be >= 0";
  if (!(std::isfinite(full_every_sec) && full_every_sec >= 0))
    return "optimization full_every_sec must be >= 0";
  if (service_default_iterations <= 0) return "optimization service_default_iterations must be > 0";
  return "";
}

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
    : options_(options),
      warn_(std::move(warn)),
      info_(std::move(info)),
      optimizer_(),
      keyframer_(keyframerOptions(options)),
      matcher_(options.matcher),
      odometry_history_(options.odometry_history_sec),
      last_chi2_(kNaN),
      robust_width_(options.robust.width) {
  const std::string error = options.validate();
  if (!error.empty()) throw std::invalid_argument("invalid pipeline options: " + error);
  optimizer_ = toro::TreeOptimizer(optimizerOptions());
  gate_threshold_ = gateThresholdFor(options);
}

double Pipeline::gateThresholdFor(const PipelineOptions& options) {
  // A loop closure's residual has 6 components (translation and rotation), 3 in the plane.
  return options.loop_closure_gate_confidence > 0
             ? toro::chiSquareQuantile(options.loop_closure_gate_confidence, options.planar ? 3 : 6) *
                   options.loop_closure_gate_variance_factor
             : std::numeric_limits<double>::infinity();
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
      step ? optimizer_.graph().pose(keyframes_.newest().id) * step->previous_T_current : sample.odom_T_base;
  const toro::NodeId previous = keyframes_.empty() ? -1 : keyframes_.newest().id;
  optimizer_.addNode(id, pose);
  ++revision_;
  keyframes_.append(KeyframeRecord{id, sample.stamp, sample.odom_T_base, next_keyframe_after_gap_});
  next_keyframe_after_gap_ = false;
  if (last_full_stamp_.isZero()) last_full_stamp_ = sample.stamp;
  ++keyframes_since_full_;
  if (!step) return;
  toro::Constraint c{previous, id, step->previous_T_current, step->information.information,
                     toro::ConstraintKind::kOdometry};
  optimizer_.addConstraint(c);  // endpoints exist and the information is SPD by construction
  is_loop_closure_.push_back(false);
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
  if (msg.id_from < 0 || msg.id_to < 0) {
    // The message measures stamp_from_T_stamp_to; the constraint joins the matched keyframes.
    measurement = keyframeToStamp(match.from, msg.stamp_from) * measurement *
                  keyframeToStamp(match.to, msg.stamp_to).inverse();
  }
  toro::Constraint c{match.from, match.to, measurement, info.information, toro::ConstraintKind::kLoopClosure};
  if (gateEnabled()) beginGate(msg);
  try {
    optimizer_.addConstraint(c);
  } catch (const toro::GraphError& e) {
    before_gate_.reset();
    MatchResult refused = match;
    refused.reason = refusal::kGraph;
    refused.detail = e.what();
    refuseLoopClosure(refused, msg);
    return;
  }
  countLoopClosureInformation(info);
  is_loop_closure_.push_back(true);
  ++revision_;
  ++counters_.loop_closures_applied;
  affected_pending_ = true;
  if (counters_.loop_closures_applied <= kEarlyLoopClosures) adaptRobustWidth();
  ++loop_closures_since_full_;
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

bool Pipeline::hasScheduledWork() const { return !paused_ && (affected_pending_ || full_passes_left_ > 0); }

void Pipeline::runAffectedPass() {
  last_optimization_sec_ = timed([&] { optimizer_.iterateAffected(1); });
  ++revision_;
  ++counters_.optimization_passes;
  affected_pending_ = false;
  last_chi2_ = optimizer_.chi2();
}

void Pipeline::runFullPass() {
  last_optimization_sec_ = timed([&] { optimizer_.iterate(); });
  ++revision_;
  ++counters_.optimization_passes;
  // A full pass covers everything added so far.
  optimizer_.clearAffected();
  affected_pending_ = false;
  last_chi2_ = optimizer_.chi2();
}

bool Pipeline::runScheduledOptimization() {
  if (paused_ || optimizer_.graph().empty()) return false;
  if (affected_pending_) {
    runAffectedPass();
    settleGate();
    return true;
  }
  if (full_passes_left_ == 0 && loop_closures_since_full_ > 0 && options_.optimization.full_iterations > 0) {
    const auto& o = options_.optimization;
    const bool by_count = o.full_every_keyframes > 0 &&
                          keyframes_since_full_ >= static_cast<std::size_t>(o.full_every_keyframes);
    const bool by_time =
        o.full_every_sec > 0 && (newest_odometry_ - last_full_stamp_).toSec() >= o.full_every_sec;
    if (by_count || by_time) {
      // Restart the learning-rate schedule: the graph changed since the last round, and a rate
      // decayed over the whole run would leave new loop closures uncorrected.
      optimizer_.setIteration(0);
      full_passes_left_ = o.full_iterations;
      loop_closures_since_full_ = 0;
      keyframes_since_full_ = 0;
      last_full_stamp_ = newest_odometry_;
    }
  }
  if (full_passes_left_ == 0) return false;
  --full_passes_left_;
  runFullPass();
  if (full_passes_left_ == 0) {
    recheckLoopClosures();
    adaptRobustWidth();
  }
  return true;
}

toro::TreeOptimizerOptions Pipeline::optimizerOptions() const {
  toro::TreeOptimizerOptions out;
  out.gamma = options_.optimization.gamma;
  out.robust = options_.robust;
  out.robust.width = robust_width_;
  out.parameterization = options_.planar ? toro::Parameterization::kPlanar : toro::Parameterization::kSpatial;
  return out;
}

void Pipeline::replaceGraph(const toro::PoseGraph& graph) {
  // Replayed through the online path (addNode/addConstraint keep the given poses, as kFromGraph
  // would) rather than setGraph: that is the path every live keyframe takes, and TreeOptimizer's
  // online growth right after setGraph wrote out of bounds in the core at the time of writing
  // (see the issue 4 report).
  optimizer_ = toro::TreeOptimizer(optimizerOptions());
  for (const toro::Node& n : graph.nodes()) optimizer_.addNode(n.id, n.pose);
  for (std::size_t c = 0; c < graph.numConstraints(); ++c) {
    toro::Constraint k = graph.constraints()[c];
    k.kind = c < is_loop_closure_.size() && is_loop_closure_[c] ? toro::ConstraintKind::kLoopClosure
                                                                : toro::ConstraintKind::kOdometry;
    optimizer_.addConstraint(k);
  }
  optimizer_.clearAffected();
  ++revision_;
}

void Pipeline::adaptRobustWidth() {
  if (!options_.robust.enabled() || !(options_.robust.adaptive_width_factor > 0.0)) return;
  // The statistic that decides acceptance is each loop closure's innovation when it arrived, so
  // the width follows those of the accepted ones (settled residuals are far smaller, and would
  // narrow the width below what the next right loop closure needs after some drift).
  std::vector<double> accepted;
  const std::vector<double>& arrival = optimizer_.arrivalChi2();
  const std::vector<double>& weights = optimizer_.weights();
  for (std::size_t c = 0; c < arrival.size(); ++c)
    if (is_loop_closure_[c] && arrival[c] >= 0.0 && weights[c] >= toro::kRejectedWeight)
      accepted.push_back(arrival[c]);
  if (accepted.size() < kMinLoopClosuresToAdaptWidth) return;
  // The median, not a high percentile: robust to the few wrong ones accepted before the width
  // could narrow, and meaningful from a handful of loop closures on.
  const auto middle = accepted.begin() + static_cast<std::ptrdiff_t>(accepted.size() / 2);
  std::nth_element(accepted.begin(), middle, accepted.end());
  const double adapted = std::min(options_.robust.width, kMedianWidthFactor * *middle);
  // Only a clear change is worth it (each one re-weights every loop closure).
  if (!(adapted > 0.0) || (adapted > robust_width_ / 1.5 && adapted < robust_width_ * 1.5)) return;
  robust_width_ = adapted;
  optimizer_.setRobustWidth(adapted);
  optimizer_.refreshWeights();
  ++revision_;
}

std::vector<DownWeightedLoopClosure> Pipeline::downWeighted() const {
  std::vector<DownWeightedLoopClosure> out;
  const toro::PoseGraph& g = optimizer_.graph();
  const std::vector<double>& w = optimizer_.weights();
  for (std::size_t c = 0; c < g.numConstraints(); ++c) {
    if (!is_loop_closure_[c] || !(w[c] < toro::kRejectedWeight)) continue;
    const toro::Constraint& k = g.constraints()[c];
    out.push_back(DownWeightedLoopClosure{k.from, k.to, w[c], toro::constraintChi2(g, c)});
  }
  return out;
}

OptimizeResult Pipeline::finish(unsigned iterations) {
  OptimizeResult r;
  toro::FinishOptions o;
  if (iterations > 0) o.max_iterations = iterations;
  o.robust = optimizerOptions().robust;
  if (!toro::cholmodAvailable()) o.linear_solver = toro::LinearSolverType::kSimplicialLDLT;
  toro::PoseGraph graph = optimizer_.graph();
  try {
    const toro::FinishReport report = toro::LevenbergMarquardt(o).optimize(graph);
    r.chi2_before = report.initial_chi2;
    r.chi2_after = report.final_chi2;
    r.time_sec = report.seconds;
    r.iterations = static_cast<int>(report.iterations);
    r.message = std::to_string(report.iterations) +
                " Levenberg-Marquardt iterations, stopped: " + toro::finishStopName(report.stop);
  } catch (const std::exception& e) {
    r.message = std::string("finish failed: ") + e.what();
    return r;
  }
  replaceGraph(graph);
  last_chi2_ = r.chi2_after;
  last_optimization_sec_ = r.time_sec;
  r.success = true;
  return r;
}

OptimizeResult Pipeline::optimize(unsigned iterations, const std::string& mode) {
  OptimizeResult r;
  if (mode != "full" && mode != "finish" && !mode.empty()) {
    r.message = "unknown mode '" + mode + "' (use \"full\" or \"finish\")";
    return r;
  }
  if (optimizer_.graph().numConstraints() == 0) {
    r.message = "nothing to optimise: the graph has no constraints";
    return r;
  }
  settleGate();  // the newest loop closure's pass and test come first, as on the schedule
  affected_pending_ = false;
  full_passes_left_ = 0;
  loop_closures_since_full_ = 0;
  if (mode == "finish") return finish(iterations);
  r.iterations =
      iterations > 0 ? static_cast<int>(iterations) : options_.optimization.service_default_iterations;
  r.chi2_before = optimizer_.chi2();
  optimizer_.setIteration(0);
  r.time_sec = timed([&] {
    // A loop closure removed by the re-check leaves the others to settle: passes again (bounded).
    for (int round = 0; round < kMaxRecheckRounds; ++round) {
      for (int i = 0; i < r.iterations; ++i) optimizer_.iterate();
      if (!recheckLoopClosures()) break;
      optimizer_.setIteration(0);
    }
  });
  optimizer_.clearAffected();
  ++revision_;
  counters_.optimization_passes += r.iterations;
  affected_pending_ = false;
  full_passes_left_ = 0;
  loop_closures_since_full_ = 0;
  r.chi2_after = last_chi2_ = optimizer_.chi2();
  last_optimization_sec_ = r.time_sec;
  r.success = true;
  r.message = std::to_string(r.iterations) + " full passes";
  return r;
}

void Pipeline::clearGraph() {
  for (const LoopClosure& msg : matcher_.clear()) {
    MatchResult r;
    r.reason = refusal::kReset;
    r.detail = "the graph was reset while it waited";
    refuseLoopClosure(r, msg);
  }
  robust_width_ = options_.robust.width;
  optimizer_ = toro::TreeOptimizer(optimizerOptions());
  keyframer_.reset();
  logged_odometry_rule_.clear();
  last_odometry_.reset();
  odometry_history_.clear();
  keyframes_.clear();
  is_loop_closure_.clear();
  before_gate_.reset();
  rejected_.clear();
  newest_odometry_ = ros::Time();
  next_id_ = 0;
  affected_pending_ = false;
  loop_closures_since_full_ = keyframes_since_full_ = 0;
  last_full_stamp_ = ros::Time();
  full_passes_left_ = 0;
  last_chi2_ = kNaN;
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
  const toro::PoseGraph& g = optimizer_.graph();
  const auto& records = keyframes_.records();
  snapshot_builder_.update(optimizer_, records, is_loop_closure_);
  s->keyframes = snapshot_builder_.shareKeyframes();
  s->edges = snapshot_builder_.shareEdges();
  s->down_weighted_loop_closures = snapshot_builder_.downWeighted();
  s->robust_width = options_.robust.enabled() ? robust_width_ : 0.0;
  for (const RejectedLoopClosure& r : rejected_)
    if (g.hasNode(r.constraint.from) && g.hasNode(r.constraint.to))
      s->rejected_edges.push_back(
          SnapshotEdge{g.indexOf(r.constraint.from), g.indexOf(r.constraint.to), true, r.chi2});
  if (!records.empty()) {
    s->has_map_T_odom = true;
    s->map_T_odom = g.node(records.size() - 1).pose * records.back().odom_T_base.inverse();
    s->newest_stamp = records.back().stamp;
  }
  s->chi2 = last_chi2_;
  s->last_optimization_sec = last_optimization_sec_;
  s->pending_loop_closures = matcher_.pending();
  s->counters = counters_;
  return s;
}

PipelineStatus Pipeline::status() const {
  PipelineStatus s;
  s.keyframes = keyframes_.size();
  s.constraints = optimizer_.graph().numConstraints();
  s.pending_loop_closures = matcher_.pending();
  s.last_chi2 = last_chi2_;
  s.last_optimization_sec = last_optimization_sec_;
  s.paused = paused_;
  s.counters = counters_;
  s.rejected = rejected_;
  s.odometry_covariance_rule = keyframer_.ruleDescription();
  s.loop_closure_covariance_rule = loop_closure_rule_;
  s.down_weighted = downWeighted();
  s.robust_width = options_.robust.enabled() ? robust_width_ : 0.0;
  return s;
}

}  // namespace toro_ros
