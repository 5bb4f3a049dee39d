#include "toro_ros/offline/offline_output.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include <geometry_msgs/PoseStamped.h>
#include <nav_msgs/Path.h>
#include <rosbag/bag.h>
#include <rosbag/exceptions.h>
#include <tf2_msgs/TFMessage.h>

#include "toro_ros/core/metrics.h"
#include "toro_ros/pipeline/msg_conversion.h"

namespace toro_ros {
namespace offline {

namespace {

std::vector<toro::Pose3> correctedPoses(const Pipeline& p) {
  std::vector<toro::Pose3> out;
  for (const toro::Node& n : p.graph().nodes()) out.push_back(n.pose);
  return out;
}

toro::PoseGraph atOdometryPoses(const Pipeline& p) {
  toro::PoseGraph g = p.graph();
  const auto& records = p.keyframes().records();
  for (std::size_t i = 0; i < records.size(); ++i) g.setPoseAt(i, records[i].odom_T_base);
  return g;
}

// JSON number (JSON has no NaN / inf).
std::string num(double v) {
  if (!std::isfinite(v)) return "null";
  std::ostringstream s;
  s.precision(10);
  s << v;
  return s.str();
}

std::string vec3(const toro::Vector3& v) {
  return "[" + num(v.x()) + ", " + num(v.y()) + ", " + num(v.z()) + "]";
}

std::string jsonString(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') out += '\\';
    if (static_cast<unsigned char>(c) >= 0x20) out += c;
  }
  return out + "\"";
}

void writeErrorJson(std::ostream& out, const char* name, const TrajectoryError& e) {
  out << "    " << jsonString(name) << ": {\"poses\": " << e.poses << ", \"rmse_m\": " << num(e.rmse_m)
      << ", \"mean_m\": " << num(e.mean_m) << ", \"max_m\": " << num(e.max_m)
      << ", \"final_m\": " << num(e.final_m) << ", \"mean_rotation_rad\": " << num(e.mean_rotation_rad)
      << ", \"rmse_aligned_m\": " << num(e.rmse_aligned_m) << "}";
}

void writeKeyframesJson(std::ostream& out, Pipeline& p, const OfflineOptions& options) {
  std::unique_ptr<TruthTrajectory> truth;
  if (!options.truth_path.empty())
    truth = std::make_unique<TruthTrajectory>(TruthTrajectory::load(options.truth_path));
  const auto& records = p.keyframes().records();
  out << "  \"trajectory\": [\n";
  for (std::size_t i = 0; i < records.size(); ++i) {
    out << "    {\"id\": " << records[i].id << ", \"stamp\": " << num(records[i].stamp.toSec())
        << ", \"odometry\": " << vec3(records[i].odom_T_base.translation())
        << ", \"corrected\": " << vec3(p.graph().node(i).pose.translation());
    toro::Pose3 t;
    if (truth && truth->at(records[i].stamp, &t)) out << ", \"truth\": " << vec3(t.translation());
    out << "}" << (i + 1 < records.size() ? ",\n" : "\n");
  }
  out << "  ],\n";
}

void writeLoopClosuresJson(std::ostream& out, Pipeline& p, const toro::PoseGraph& before) {
  const std::shared_ptr<const Snapshot> s = p.makeSnapshot();
  out << "  \"loop_closures\": [";
  bool first = true;
  for (std::size_t c = 0; c < s->edges.size(); ++c) {
    const SnapshotEdge& e = s->edges[c];
    if (!e.loop_closure) continue;
    out << (first ? "\n" : ",\n") << "    {\"from\": " << e.from_index << ", \"to\": " << e.to_index
        << ", \"chi2_before\": " << num(toro::constraintChi2(before, c))
        << ", \"chi2_after\": " << num(e.chi2) << "}";
    first = false;
  }
  out << "\n  ],\n";
}

void writeOptimalityJson(std::ostream& out, const std::vector<OfflineRun::Optimality>& samples) {
  out << "  \"optimality\": [";
  for (std::size_t i = 0; i < samples.size(); ++i) {
    const OfflineRun::Optimality& o = samples[i];
    out << (i ? ",\n" : "\n") << "    {\"stamp\": " << num(o.stamp_sec)
        << ", \"constraints\": " << o.constraints << ", \"published_chi2\": " << num(o.published_chi2)
        << ", \"optimum_chi2\": " << num(o.optimum_chi2)
        << ", \"published_weighted_chi2\": " << num(o.published_weighted_chi2)
        << ", \"weighted_optimum_chi2\": " << num(o.weighted_optimum_chi2)
        << ", \"since_loop_closure\": " << num(o.since_loop_closure_sec) << "}";
  }
  out << "\n  ],\n";
}

void writeCurveJson(std::ostream& out, const std::vector<CurvePoint>& curve) {
  out << "  \"curve\": [";
  for (std::size_t i = 0; i < curve.size(); ++i) {
    const CurvePoint& c = curve[i];
    out << (i ? ",\n" : "\n") << "    {\"pass\": " << c.pass << ", \"stamp\": " << num(c.stamp_sec)
        << ", \"keyframes\": " << c.keyframes << ", \"constraints\": " << c.constraints
        << ", \"chi2\": " << num(c.chi2) << ", \"final\": " << (c.final_phase ? "true" : "false") << "}";
  }
  out << "\n  ],\n";
}

void writeSummaryJson(const std::string& path, Pipeline& p, const OfflineSummary& s,
                      const OfflineOptions& options) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error(path + ": cannot write the summary");
  const PipelineCounters& k = s.status.counters;
  out << "{\n  \"bag\": " << jsonString(s.bag) << ",\n  \"messages\": " << s.run.messages
      << ",\n  \"bag_duration_sec\": " << num(s.run.bag_duration_sec)
      << ",\n  \"wall_sec\": " << num(s.run.wall_sec)
      << ",\n  \"optimization_sec\": " << num(s.run.optimization_sec)
      << ",\n  \"blas_kernels\": " << jsonString(s.run.blas_kernels)
      << ",\n  \"keyframes\": " << s.status.keyframes << ",\n  \"constraints\": " << s.status.constraints
      << ",\n  \"odometry_messages\": " << k.odometry_messages
      << ",\n  \"odometry_refused\": " << k.odometry_refused
      << ",\n  \"loop_closures_received\": " << k.loop_closures_received
      << ",\n  \"loop_closures_applied\": " << k.loop_closures_applied
      << ",\n  \"loop_closures_refused\": " << k.loop_closures_refused
      << ",\n  \"loop_closures_pending\": " << s.status.pending_loop_closures
      << ",\n  \"optimization_passes\": " << k.optimization_passes << ",\n  \"finishes\": " << s.run.finishes
      << ",\n  \"finishes_merged\": " << k.finishes_merged
      << ",\n  \"finishes_from_scratch\": " << k.finishes_from_scratch
      << ",\n  \"finishes_from_scratch_kept\": " << k.finishes_from_scratch_kept
      << ",\n  \"odometry_covariance_rule\": " << jsonString(s.status.odometry_covariance_rule)
      << ",\n  \"odometry_steps_default\": " << k.odometry_steps_default
      << ",\n  \"odometry_steps_partly_default\": " << k.odometry_steps_partly_default
      << ",\n  \"odometry_steps_repaired\": " << k.odometry_steps_repaired
      << ",\n  \"loop_closure_covariance_rule\": " << jsonString(s.status.loop_closure_covariance_rule)
      << ",\n  \"loop_closures_default_covariance\": " << k.loop_closures_default
      << ",\n  \"loop_closures_partly_default_covariance\": " << k.loop_closures_partly_default
      << ",\n  \"loop_closures_repaired_covariance\": " << k.loop_closures_repaired
      << ",\n  \"final_iterations\": " << s.run.final_result.iterations
      << ",\n  \"chi2_odometry\": " << num(s.chi2_odometry)
      << ",\n  \"chi2_corrected\": " << num(s.chi2_corrected) << ",\n  \"refused_by_reason\": {";
  bool first = true;
  for (const auto& [reason, count] : k.refused_by_reason) {
    out << (first ? "" : ", ") << jsonString(reason) << ": " << count;
    first = false;
  }
  out << "},\n";
  if (s.has_score) {
    out << "  \"score\": {\n";
    writeErrorJson(out, "odometry", s.score.odometry);
    out << ",\n";
    writeErrorJson(out, "corrected", s.score.corrected);
    out << "\n  },\n";
  }
  writeCurveJson(out, s.run.curve);
  writeOptimalityJson(out, s.run.optimality);
  out << "  \"loop_closures_held\": " << s.status.counters.loop_closures_held
      << ",\n  \"loop_closures_released\": " << s.status.counters.loop_closures_released
      << ",\n  \"loop_closures_released_predicted\": " << s.status.counters.loop_closures_released_predicted
      << ",\n";
  out << "  \"down_weighted_loop_closures\": [";
  for (std::size_t i = 0; i < s.status.down_weighted.size(); ++i) {
    const DownWeightedLoopClosure& d = s.status.down_weighted[i];
    out << (i ? "," : "") << (i % 4 ? " " : "\n    ") << "[" << d.from << ", " << d.to << ", " << num(d.weight) << "]";
  }
  out << "\n  ],\n";
  out << "  \"loop_closures_down_weighted\": " << s.status.down_weighted.size()
      << ",\n  \"robust_width\": " << num(s.status.robust_width) << ",\n  \"robot_in_map\": [";
  for (std::size_t i = 0; i < s.run.robot_in_map.size(); ++i) {
    const OfflineRun::RobotInMap& r = s.run.robot_in_map[i];
    out << (i ? "," : "") << (i % 4 ? " " : "\n    ") << "[" << num(r.stamp_sec) << ", " << num(r.position.x()) << ", "
        << num(r.position.y()) << ", " << num(r.position.z()) << "]";
  }
  // The same samples' map_T_odom: [stamp, x, y, z, qx, qy, qz, qw].
  out << "\n  ],\n  \"map_T_odom\": [";
  for (std::size_t i = 0; i < s.run.robot_in_map.size(); ++i) {
    const OfflineRun::RobotInMap& r = s.run.robot_in_map[i];
    const toro::Vector3& t = r.map_T_odom.translation();
    const toro::Quaternion& q = r.map_T_odom.rotation();
    out << (i ? "," : "") << (i % 2 ? " " : "\n    ") << "[" << num(r.stamp_sec) << ", " << num(t.x()) << ", "
        << num(t.y()) << ", " << num(t.z()) << ", " << num(q.x()) << ", " << num(q.y()) << ", " << num(q.z()) << ", "
        << num(q.w()) << "]";
  }
  out << "\n  ],\n";
  writeLoopClosuresJson(out, p, atOdometryPoses(p));
  writeKeyframesJson(out, p, options);
  out << "  \"format\": \"toro_offline summary 1\"\n}\n";
  if (!out) throw std::runtime_error(path + ": write failed");
}

void writeCorrectedBag(const std::string& path, const Pipeline& p, const NodeOptions& node) {
  const auto& records = p.keyframes().records();
  if (records.empty()) return;
  try {
    rosbag::Bag bag(path, rosbag::bagmode::Write);
    nav_msgs::Path path_msg;
    path_msg.header.frame_id = node.map_frame;
    path_msg.header.stamp = records.back().stamp;
    for (std::size_t i = 0; i < records.size(); ++i) {
      const toro::Pose3& map_T_base = p.graph().node(i).pose;
      geometry_msgs::PoseStamped pose;
      pose.header.stamp = records[i].stamp;
      pose.header.frame_id = node.map_frame;
      pose.pose = poseToMsg(map_T_base);
      bag.write("/corrected_pose", records[i].stamp, pose);
      path_msg.poses.push_back(pose);
      geometry_msgs::TransformStamped tf;
      tf.header = pose.header;
      tf.child_frame_id = node.odom_frame;
      tf.transform = transformToMsg(map_T_base * records[i].odom_T_base.inverse());
      tf2_msgs::TFMessage tf_msg;
      tf_msg.transforms.push_back(tf);
      bag.write("/tf", records[i].stamp, tf_msg);
    }
    bag.write("/corrected_path", records.back().stamp, path_msg);
  } catch (const rosbag::BagException& e) {
    throw std::runtime_error(path + ": cannot write the bag: " + e.what());
  }
}

}  // namespace

OfflineSummary summarize(OfflineRunner& runner, const OfflineRun& run, const OfflineOptions& options) {
  OfflineSummary s;
  s.bag = options.bag_path;
  s.run = run;
  Pipeline& p = runner.pipeline();
  s.status = p.status();
  s.chi2_odometry = toro::g2oChi2(atOdometryPoses(p));
  s.chi2_corrected = toro::g2oChi2(p.graph());
  if (!options.truth_path.empty()) {
    s.score =
        scoreKeyframes(p.keyframes().records(), correctedPoses(p), TruthTrajectory::load(options.truth_path));
    s.has_score = true;
  }
  return s;
}

void writeOutputs(OfflineRunner& runner, const OfflineSummary& summary, const OfflineOptions& options) {
  std::error_code ec;
  std::filesystem::create_directories(options.output_dir, ec);
  if (ec)
    throw std::runtime_error(options.output_dir + ": cannot create the output directory: " + ec.message());
  Pipeline& p = runner.pipeline();
  const std::string error = p.saveGraph(options.output_dir + "/corrected.g2o");
  if (!error.empty()) throw std::runtime_error(error);
  writeCorrectedBag(options.output_dir + "/corrected_poses.bag", p, runner.nodeOptions());
  writeSummaryJson(options.output_dir + "/summary.json", p, summary, options);
}

std::string describeSummary(const OfflineSummary& s) {
  std::ostringstream out;
  const PipelineCounters& k = s.status.counters;
  out << s.run.messages << " messages (" << s.run.bag_duration_sec << " s of bag) in " << s.run.wall_sec
      << " s wall, " << s.run.optimization_sec << " s optimising\n"
      << s.status.keyframes << " keyframes, " << s.status.constraints
      << " constraints; loop closures: " << k.loop_closures_received << " received, "
      << k.loop_closures_applied << " applied, " << k.loop_closures_refused << " refused, "
      << s.status.pending_loop_closures << " pending\n";
  // Applied is not in the map: a loop closure at weight 0 moves nothing (a lone right one the
  // support never released looks, in the counts above, like one that corrected the map).
  if (!s.status.down_weighted.empty()) {
    const std::uint64_t still_held = std::min<std::uint64_t>(
        k.loop_closures_held - std::min(k.loop_closures_held, k.loop_closures_released),
        s.status.down_weighted.size());
    out << "of them " << s.status.down_weighted.size() << " weighted below 0.5 at the end (robust), "
        << still_held << " of those held since they arrived: nothing supported them "
        << "(robust_hold_until_supported: false applies each at its robust weight)\n";
  }
  out << "chi2 before (odometry) " << s.chi2_odometry << ", after " << s.chi2_corrected << " ("
      << k.optimization_passes << " passes, " << s.run.finishes << " finishes)\n";
  if (s.has_score) out << describeScore(s.score);
  return out.str();
}

}  // namespace offline
}  // namespace toro_ros
