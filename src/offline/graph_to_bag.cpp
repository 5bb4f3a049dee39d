#include "toro_ros/offline/graph_to_bag.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <stdexcept>

#include <rosbag/bag.h>
#include <tf2_msgs/TFMessage.h>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/core/tree_optimizer.h"
#include "toro_ros/offline/robot_messages.h"
#include "toro_ros/pipeline/covariance_conversion.h"
#include "toro_ros/pipeline/persistence.h"

namespace toro_ros {
namespace offline {

namespace {

bool positive(double v) { return std::isfinite(v) && v > 0; }

// Whole odometry periods a step lasts (at least one, so every keyframe has its own message).
long stepSamples(const toro::Pose3& step, const GraphToBagOptions& o) {
  if (o.keyframe_period_sec > 0) return std::lround(o.keyframe_period_sec * o.odometry_rate_hz);
  const double sec = std::max(step.translation().norm() / o.speed_mps, step.angle() / o.angular_speed_radps);
  // The small margin keeps a duration that is a whole number of periods from rounding up.
  return std::max(1L, static_cast<long>(std::ceil(sec * o.odometry_rate_hz - 1e-9)));
}

toro::PoseGraph withPoses(const toro::PoseGraph& graph, const std::vector<toro::Pose3>& poses) {
  toro::PoseGraph out = graph;
  for (std::size_t i = 0; i < poses.size(); ++i) out.setPoseAt(i, poses[i]);
  return out;
}

// Poses re-expressed in the frame of the first one (the odom frame's origin is where the robot started).
std::vector<toro::Pose3> rebased(const toro::PoseGraph& graph) {
  std::vector<toro::Pose3> out;
  const toro::Pose3 first_inverse = graph.node(0).pose.inverse();
  for (const toro::Node& n : graph.nodes()) out.push_back(first_inverse * n.pose);
  return out;
}

// A truth file without VERTEX lines (e.g. GTSAM's sphere2500_groundtruth: noise-free measurements
// only) gives its poses by chaining its consecutive-id constraints.
toro::PoseGraph chainedTruth(const toro::PoseGraph& truth, const std::string& path) {
  const RobotTimeline chain = makeTimeline(sortedById(truth), GraphToBagOptions(), path);
  toro::PoseGraph out = truth;
  for (std::size_t k = 0; k < chain.ids.size(); ++k) out.setPose(chain.ids[k], chain.odom_T_base[k]);
  return out;
}

std::vector<toro::Pose3> truthPoses(const toro::PoseGraph& input, const std::string& path) {
  toro::ReadReport report;
  toro::PoseGraph truth = toro::readGraph(path, toro::ReadOptions(), &report);
  if (!report.has_vertices) truth = chainedTruth(truth, path);
  toro::PoseGraph ordered = input;
  for (std::size_t i = 0; i < input.numNodes(); ++i) {
    const toro::NodeId id = input.node(i).id;
    if (!truth.hasNode(id))
      throw std::runtime_error(path + ": ground truth has no node " + std::to_string(id) +
                               " (the input has it)");
    ordered.setPoseAt(i, truth.pose(id));
  }
  return rebased(ordered);
}

std::vector<toro::Pose3> referencePoses(const toro::PoseGraph& input, int iterations) {
  toro::TreeOptimizer optimizer;
  optimizer.setGraph(input, toro::InitialGuess::kChainOnTree);
  for (int i = 0; i < iterations; ++i) optimizer.iterate();
  return rebased(optimizer.graph());
}

void writeScoringFiles(const toro::PoseGraph& graph, const RobotTimeline& t, const GraphToBagOptions& o,
                       GraphToBagResult* result) {
  const std::string stem = bagStem(o.output_bag);
  const std::string odometry_path = stem + ".odometry.g2o";
  toro::writeGraph(withPoses(graph, t.odom_T_base), odometry_path);
  Sidecar sidecar;
  for (std::size_t k = 0; k < t.ids.size(); ++k)
    sidecar.keyframes.push_back(KeyframeRecord{t.ids[k], t.stampOfKeyframe(k), t.odom_T_base[k]});
  for (std::size_t c = 0; c < t.is_loop_closure.size(); ++c)
    if (t.is_loop_closure[c]) sidecar.loop_closures.push_back(c);
  writeSidecar(sidecarPath(odometry_path), sidecar);
  result->written.push_back(odometry_path);
  result->written.push_back(sidecarPath(odometry_path));
  if (!o.ground_truth_path.empty()) {
    toro::writeGraph(withPoses(graph, truthPoses(graph, o.ground_truth_path)), stem + ".truth.g2o");
    result->written.push_back(stem + ".truth.g2o");
  } else if (o.reference_iterations > 0) {
    toro::writeGraph(withPoses(graph, referencePoses(graph, o.reference_iterations)),
                     stem + ".reference.g2o");
    result->written.push_back(stem + ".reference.g2o");
  }
}

}  // namespace

std::string GraphToBagOptions::validate() const {
  if (input_path.empty()) return "input graph file: missing";
  if (output_bag.size() < 5 || output_bag.substr(output_bag.size() - 4) != ".bag")
    return "output bag '" + output_bag + "': must end in .bag";
  if (!positive(odometry_rate_hz) || odometry_rate_hz > 1000) return "odometry_rate_hz must be in (0, 1000]";
  if (!positive(speed_mps)) return "speed_mps must be > 0";
  if (!positive(angular_speed_radps)) return "angular_speed_radps must be > 0";
  if (!(std::isfinite(keyframe_period_sec) && keyframe_period_sec >= 0))
    return "keyframe_period_sec must be >= 0";
  if (keyframe_period_sec > 0) {
    const double samples = keyframe_period_sec * odometry_rate_hz;
    if (samples < 1 - 1e-9 || std::abs(samples - std::round(samples)) > 1e-6)
      return "keyframe_period_sec must be a whole multiple (>= 1) of 1 / odometry_rate_hz";
  }
  if (!(std::isfinite(start_sec) && start_sec > 0 && start_sec < 4e9)) return "start_sec must be in (0, 4e9)";
  if (!(std::isfinite(loop_closure_latency_sec) && loop_closure_latency_sec >= 0 &&
        loop_closure_latency_sec < 1.0 / odometry_rate_hz))
    return "loop_closure_latency_sec must be >= 0 and shorter than one odometry period";
  if (reference_iterations < 0) return "reference_iterations must be >= 0";
  for (const std::string* s : {&odom_frame, &base_frame, &odom_topic, &loop_closure_topic, &tf_topic})
    if (s->empty()) return "frame and topic names must not be empty";
  return "";
}

std::string bagStem(const std::string& bag_path) {
  const std::string suffix = ".bag";
  if (bag_path.size() > suffix.size() &&
      bag_path.compare(bag_path.size() - suffix.size(), suffix.size(), suffix) == 0)
    return bag_path.substr(0, bag_path.size() - suffix.size());
  return bag_path;
}

RobotTimeline makeTimeline(const toro::PoseGraph& graph, const GraphToBagOptions& o,
                           const std::string& source) {
  if (graph.numNodes() < 2) throw std::runtime_error(source + ": the graph needs at least two nodes");
  RobotTimeline t;
  t.sample_period = ros::Duration().fromNSec(std::llround(1e9 / o.odometry_rate_hz));
  t.start = ros::Time(o.start_sec);
  std::map<std::pair<toro::NodeId, toro::NodeId>, std::size_t> first_between;
  for (std::size_t c = graph.numConstraints(); c-- > 0;) {
    const toro::Constraint& k = graph.constraints()[c];
    first_between[{k.from, k.to}] = c;  // visited backwards: the first one wins
  }
  std::vector<toro::NodeId> ids;
  for (const toro::Node& n : graph.nodes()) ids.push_back(n.id);
  std::sort(ids.begin(), ids.end());
  t.ids = ids;
  t.is_loop_closure.assign(graph.numConstraints(), true);
  t.odom_T_base.push_back(toro::Pose3());
  t.sample_of_keyframe.push_back(0);
  for (std::size_t k = 0; k + 1 < ids.size(); ++k) {
    // Forward k -> k+1, else the reverse (TORO's sphere files have some odometry edges backwards).
    auto it = first_between.find({ids[k], ids[k + 1]});
    const bool reversed = it == first_between.end();
    if (reversed) it = first_between.find({ids[k + 1], ids[k]});
    if (it == first_between.end())
      throw std::runtime_error(source + ": no constraint between node " + std::to_string(ids[k]) +
                               " and node " + std::to_string(ids[k + 1]) +
                               " (consecutive ids): the odometry chain is broken");
    const toro::Pose3& measurement = graph.constraints()[it->second].measurement;
    const toro::Pose3 step = reversed ? measurement.inverse() : measurement;
    t.odometry_constraint.push_back(it->second);
    t.odometry_reversed.push_back(reversed);
    t.is_loop_closure[it->second] = false;
    t.odom_T_base.push_back(t.odom_T_base.back() * step);
    t.sample_of_keyframe.push_back(t.sample_of_keyframe.back() + stepSamples(step, o));
  }
  addCovariances(graph, &t);
  return t;
}

GraphToBagResult graphToBag(const GraphToBagOptions& options) {
  const std::string invalid = options.validate();
  if (!invalid.empty()) throw std::invalid_argument(invalid);
  toro::PoseGraph graph = toro::readGraph(options.input_path);
  // Dense indices in id order, so index k is keyframe k everywhere below.
  graph = sortedById(graph);
  const RobotTimeline timeline = makeTimeline(graph, options, options.input_path);
  GraphToBagResult result;
  writeRobotBag(graph, timeline, options, &result);
  writeScoringFiles(graph, timeline, options, &result);
  return result;
}

}  // namespace offline
}  // namespace toro_ros
