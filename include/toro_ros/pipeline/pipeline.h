// The live behaviour without the transport: odometry and loop-closure messages in stamp order in,
// keyframes, constraints, optimisation passes and Snapshots out.  Used by the node in real time and
// by an offline runner from a bag; it never reads wall time (except to report how long an
// optimisation took) and starts no threads, so a given call sequence gives the same graph.
#pragma once

#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <unordered_set>
#include <vector>

#include <nav_msgs/Odometry.h>

#include "toro_ros/LoopClosure.h"
#include "toro_ros/core/robust_kernel.h"
#include "toro_ros/core/tree_optimizer.h"
#include "toro_ros/pipeline/graph_file.h"
#include "toro_ros/pipeline/keyframer.h"
#include "toro_ros/pipeline/loop_closure_matcher.h"
#include "toro_ros/pipeline/map_optimizer.h"
#include "toro_ros/pipeline/odometry_history.h"
#include "toro_ros/pipeline/snapshot.h"
#include "toro_ros/pipeline/snapshot_builder.h"

namespace toro_ros {

// How the odometry of a run that resumed a saved map (loadGraph) joins the saved keyframes.
enum class ResumeLink {
  // The odometry frame is the saved run's (only the node restarted; the odometry source ran on):
  // the first new keyframe is linked to the newest saved one by the odometry between them.
  kContinue,
  // The odometry restarted from its own origin at the pose where the saved run ended (the whole
  // robot restarted where it stopped): the first new odometry message becomes a keyframe linked to
  // the newest saved one by the identity, with resume_link_stddev.
  kLastPose,
};
// "continue" | "last_pose"; nullopt for anything else.
std::optional<ResumeLink> resumeLinkFromString(const std::string& s);
std::string toString(ResumeLink link);

struct PersistenceOptions {
  // Where the graph (+ "<path>.stamps") is saved atomically every autosave_period_sec of message
  // time when it changed, and when the owner calls autosave() (the node: on shutdown).  Empty: off.
  std::string autosave_path;
  double autosave_period_sec = 30.0;  // > 0
  ResumeLink resume_link = ResumeLink::kContinue;
  DefaultStddev resume_link_stddev{0.5, 0.2};  // the kLastPose link: where the robot was put down
  std::string validate() const;
};

struct PipelineOptions {
  // Odometry whose header.frame_id is set and differs is refused (its poses are in another frame,
  // so map -> odom_frame would be wrong).  Empty: any frame.  The node sets it to its odom_frame.
  std::string odom_frame;
  KeyframerOptions keyframer;
  LoopClosureMatchOptions matcher;
  DefaultStddev loop_closure_default_stddev{0.1, 0.05};
  // Loop-closure variances at or above this (m^2 / rad^2) mark unmeasured axes (covariance_rules.h).
  double loop_closure_unmeasured_variance = kDefaultUnmeasuredVariance;
  OptimizationOptions optimization;
  // Odometry more than this older than the newest resets the graph (a bag restarted); smaller
  // steps back are refused as out of order.
  double time_jump_reset_sec = 1.0;
  // Odometry kept at full rate to move a loop closure from the stamps it names onto its keyframes
  // (the motion between a stamp and its keyframe); older messages are thinned (odometry_history.h).
  double odometry_history_sec = 60.0;
  // Loop-closure gate (see pipeline_gate.cpp): after a new loop closure's affected pass, its g2o
  // chi2 must not exceed the chi-square quantile at this confidence, with 6 degrees of freedom (3
  // while every measurement is planar, as in planar mode), else the graph is restored without it
  // and it is kept as rejected.  0 disables the gate; must be < 1.
  // Off by default: the test is only as good as the declared covariances, and with the default
  // odometry covariances ordinary wheel drift (3 %, 0.02 rad/m) fails it for right loop closures.
  double loop_closure_gate_confidence = 0.0;
  // The a-posteriori variance factor of the covariances the gate sees (odometry and loop closures):
  // their true covariances are taken to be this times the declared ones, so the chi2 threshold is
  // the quantile times this.  1 trusts the declared covariances; < 1 for senders known to declare
  // them too large (e.g. parking-garage.g2o, whose residuals are ~1e-4 of its declared ones).
  double loop_closure_gate_variance_factor = 1.0;
  // Robust loop closures (core robust_kernel.h): each loop closure's weight in TORO's passes and in
  // the finish comes from its residual, from the moment it arrives, so a wrong one does not bend
  // the map; odometry stays Gaussian.  On (DCS) by default; kernel kNone turns it off.  The width
  // adapts to the accepted loop closures' residuals after each full round (adaptive_width_factor).
  toro::RobustOptions robust{toro::RobustKernel::kDcs};
  PersistenceOptions persistence;
  // Planar robots (a floor): every odometry pose and loop-closure measurement is projected onto
  // the plane at input (x, y and the heading kept; z, roll and pitch dropped; toro/core/planar.h),
  // their covariances are read from the x, y, yaw rows only (planarCovariance), the optimisers work
  // in SE(2), and everything the pipeline gives out is exactly planar: corrected poses and
  // map -> odom with z = 0 and roll = pitch = 0, saved graphs as 2D files.  A loaded 3D graph is
  // projected the same way.
  bool planar = false;
  std::string validate() const;
};

// "dcs" | "cauchy" | "huber" (| "none").
std::string toString(toro::RobustKernel kernel);

// Status for ~get_status and diagnostics.
struct PipelineStatus {
  std::size_t keyframes = 0;
  std::size_t constraints = 0;
  std::size_t pending_loop_closures = 0;
  double last_chi2 = 0.0;  // NaN before any optimisation
  double last_optimization_sec = 0.0;
  bool paused = false;
  PipelineCounters counters;
  std::vector<RejectedLoopClosure> rejected;
  // How covariances are read: the odometry rule in use (Keyframer::ruleDescription) and the axes
  // of the newest applied loop closure's covariance ("" before the first).
  std::string odometry_covariance_rule;
  std::string loop_closure_covariance_rule;
  // Loop closures whose robust weight is now below toro::kRejectedWeight (they stay in the graph
  // and regain weight when the map comes to agree with them), and the kernel width in use.
  std::vector<DownWeightedLoopClosure> down_weighted;
  double robust_width = 0.0;
  // The newest background finish (nullopt before the first) and whether one is running now.
  std::optional<FinishRecord> last_finish;
  bool finish_running = false;
  // Why the background finish is off for this map ("" while it is not; MapOptimizer::finishOffReason).
  std::string finish_off_reason;
};

class Pipeline {
 public:
  using WarningSink = std::function<void(const std::string&)>;
  using InfoSink = std::function<void(const std::string&)>;

  // Throws std::invalid_argument if options.validate() complains.  `info` hears what is worth one
  // line in the log but is no problem (which covariance rule is in use).
  explicit Pipeline(const PipelineOptions& options, WarningSink warn = nullptr, InfoSink info = nullptr);

  // Grows the graph (no optimisation here).  Refusals are counted and reported to the sink.
  void handleOdometry(const nav_msgs::Odometry& msg);
  void handleLoopClosure(const LoopClosure& msg);

  // Runs what is due: one affected pass if loop closures were applied since the last call, else one
  // pass of a due full round (rounds are spread over calls so the caller can take new messages in
  // between).  Nothing while paused.  Returns true if poses changed.
  bool runScheduledOptimization();
  // True if a full round has passes left (the caller should call runScheduledOptimization again).
  bool hasScheduledWork() const;

  // ~optimize: mode "full" (or empty): `iterations` TORO passes over all constraints (0: the
  // configured default), then the finish when optimization.background_finish is on; "finish":
  // the core's sparse Levenberg-Marquardt on the g2o chi2 with at most `iterations` iterations
  // (0: its default).
  OptimizeResult optimize(unsigned iterations, const std::string& mode);
  // The background finish (MapOptimizer): a job when one is due (run it anywhere with
  // runFinishJob, then give the outcome to mergeFinish, on the pipeline's thread).  Nothing while
  // paused.  mergeFinish returns true if the outcome was taken into the map.
  std::optional<FinishJob> takeFinishJob();
  // A finish is due but not taken yet (it waits for finish_min_interval_sec, for a pass, or for
  // the one out to come back): a live caller that would sleep should look again soon.
  bool finishPending() const { return !paused_ && map_.finishPending(); }
  // The schedule's clock is message time, the newest odometry stamp.  A live caller reports how
  // long no odometry has come (wall seconds; every odometry message resets it): the clock runs on
  // by that much, so a finish due by time still comes once a robot's odometry stops (a bag ended,
  // a paused driver) while loop closures still arrive.  Offline nobody calls it: replays are
  // deterministic.
  void setOdometryQuietSec(double sec) { odometry_quiet_sec_ = sec > 0.0 ? sec : 0.0; }
  bool mergeFinish(const FinishOutcome& outcome);
  // MapOptimizer::optimumJob: the finish to the map's optimum under its robust weights, to measure.
  FinishJob optimumJob() const { return map_.optimumJob(); }
  void setPaused(bool paused) { paused_ = paused; }
  bool paused() const { return paused_; }
  // Forgets the graph, keyframes and pending loop closures (counters survive; resets counted).
  void reset(const std::string& why);
  // Save/load the graph (format by extension) and a "<path>.stamps" sidecar (see persistence.h).
  // Empty string on success, else the error.  A failed load leaves the pipeline untouched.  After
  // a load the map is resumed: odometry stamped at or before the newest loaded keyframe is refused
  // (it is already in the map; no time-jump reset), and the next newer odometry is joined to the
  // loaded keyframes by options().persistence.resume_link.  Loop closures sent (header stamp) at
  // or before that keyframe are refused too, so replaying a bag from its start into the resumed
  // map does not add its loop closures twice.
  // The path overloads take an operator's path (GraphFileRef(path)); the node's services pass a
  // file GraphDirectory confined to its directory (errors about it never quote its content).
  std::string saveGraph(const std::string& path) const;
  std::string saveGraph(const GraphFileRef& file) const;
  std::string loadGraph(const std::string& path);
  std::string loadGraph(const GraphFileRef& file);
  // Saves to persistence.autosave_path now if it is set and the graph changed since the last
  // autosave (the node calls it on shutdown).  Empty string when saved or nothing to do.
  std::string autosave();

  // A new immutable snapshot of the current state: O(what changed since the last one) after new
  // keyframes, affected passes and weight changes; O(keyframes + constraints) after full passes,
  // a finish merge (every pose set) and a replaced graph (gate restore, re-check, reset, load)
  // (snapshot_builder.h).
  std::shared_ptr<const Snapshot> makeSnapshot();
  PipelineStatus status() const;
  // The counters alone (status() copies lists too).
  const PipelineCounters& counters() const { return counters_; }
  const toro::PoseGraph& graph() const { return map_.graph(); }
  const KeyframeIndex& keyframes() const { return keyframes_; }
  // Loop closures the gate refused, in the order they were refused.
  const std::vector<RejectedLoopClosure>& rejectedLoopClosures() const { return map_.rejected(); }
  // The gate's chi2 threshold (infinity when the gate is off).
  double gateThreshold() const { return map_.gateThreshold(); }
  const PipelineOptions& options() const { return options_; }
  // The options of the pipeline's TORO optimiser now (gamma, robust kernel with the adapted width).
  toro::TreeOptimizerOptions optimizerOptions() const { return map_.optimizerOptions(); }
  // Run-time tuning (pipeline_live_options.cpp): takes from `options` the values that are safe
  // to change while running (keyframe thresholds, the optimisation schedule, the gate, the robust
  // kernel's width and its adaptation) and keeps the others.  Empty string on success; else why
  // not, and nothing changed.
  std::string applyLiveOptions(const PipelineOptions& options);
  // Changes whenever what a snapshot shows changes (keyframes, constraints, poses, counters of
  // refusals, resets); not for odometry that makes no keyframe.  Publishers compare it.
  std::uint64_t revision() const { return revision_ + map_.revision(); }

 private:
  void addKeyframe(const OdometrySample& sample);
  // Makes `sample` the newest keyframe; with a step, joined to the previous newest by it.
  void appendKeyframe(const OdometrySample& sample, const std::optional<OdometryStep>& step);
  // The first odometry after a load (pipeline_persistence.cpp): false if `sample` is refused.
  bool resumeWith(const OdometrySample& sample);
  void autosaveIfDue(const ros::Time& stamp);
  void keyframeForStamps(const LoopClosure& msg);
  void applyLoopClosure(const LoopClosure& msg, const MatchResult& match);
  // keyframe_T_stamp from the odometry at the stamp (pipeline_input.cpp).
  toro::Pose3 keyframeToStamp(toro::NodeId keyframe, const ros::Time& stamp) const;
  // The covariance of that offset (right perturbation, angle units), from the odometry step it
  // lies on; zero at the keyframe's own stamp.
  toro::Matrix6 keyframeToStampCovariance(toro::NodeId keyframe, const ros::Time& stamp,
                                          const toro::Pose3& keyframe_T_stamp);
  // odom_T_base at `stamp`: the full-rate history where it covers the stamp, else interpolated
  // between the keyframes (or the newest odometry) around it; nullopt outside the trajectory.
  std::optional<toro::Pose3> odometryPoseAt(const ros::Time& stamp) const;
  // Covariance accounting and the once-only log lines (pipeline_input.cpp).
  void countOdometryStep(const InformationResult& information);
  void countLoopClosureInformation(const InformationResult& information);
  void releasePending();
  void refuse(const std::string& category, const std::string& detail);
  void refuseLoopClosure(const MatchResult& match, const LoopClosure& msg);
  void clearGraph();

  PipelineOptions options_;
  WarningSink warn_;
  InfoSink info_;
  PipelineCounters counters_;  // before map_, which keeps a pointer to it
  MapOptimizer map_;
  Keyframer keyframer_;
  LoopClosureMatcher matcher_;
  KeyframeIndex keyframes_;
  ros::Time newest_odometry_;
  double odometry_quiet_sec_ = 0.0;  // see setOdometryQuietSec
  // newest_odometry_, run on by odometry_quiet_sec_: the clock of the optimisation schedule.
  ros::Time scheduleClock() const;
  std::optional<OdometrySample> last_odometry_;  // the newest odometry message, keyframe or not
  OdometryHistory odometry_history_;
  toro::NodeId next_id_ = 0;
  bool paused_ = false;
  std::uint64_t generation_ = 0;
  std::uint64_t revision_ = 0;
  std::uint64_t epoch_ = 0;
  std::string logged_odometry_rule_;          // the convention last logged ("" none yet)
  std::vector<AxisReadings> logged_loop_closure_axes_;  // loop-closure readings logged so far
  std::string loop_closure_rule_;
  // The gate's part of the options (MapOptimizer::gateThreshold counts the input's degrees of freedom).
  static GateOptions gateOptionsOf(const PipelineOptions& options);
  std::unordered_set<std::uint64_t> applied_messages_;  // hashes of applied loop-closure messages
  // Persistence: set by loadGraph until newer odometry arrives; the last autosave.
  std::optional<ros::Time> resume_after_;
  // The odometry before the next keyframe was not seen (it is the first after a load): it is marked
  // after_gap so that nothing is interpolated across the gap.
  bool next_keyframe_after_gap_ = false;
  ros::Time loaded_until_;  // newest keyframe stamp of the last load (input up to it is refused)
  ros::Time last_autosave_stamp_;
  std::uint64_t autosaved_revision_ = 0;
  // The keyframes and edges of the snapshots, kept up to date from the optimiser's journal.
  SnapshotBuilder snapshot_builder_;
};

}  // namespace toro_ros
