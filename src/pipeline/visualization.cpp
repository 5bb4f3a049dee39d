#include "toro_ros/pipeline/visualization.h"

#include <algorithm>
#include <cmath>

#include "toro_ros/core/robust_kernel.h"
#include "toro_ros/pipeline/msg_conversion.h"

namespace toro_ros {

namespace {

geometry_msgs::Point point(const toro::Pose3& pose) {
  geometry_msgs::Point p;
  p.x = pose.translation().x();
  p.y = pose.translation().y();
  p.z = pose.translation().z();
  return p;
}

std_msgs::ColorRGBA rgba(float r, float g, float b, float a = 1.0f) {
  std_msgs::ColorRGBA c;
  c.r = r;
  c.g = g;
  c.b = b;
  c.a = a;
  return c;
}

visualization_msgs::Marker baseMarker(const std::string& frame, const ros::Time& stamp, const char* ns,
                                      int type) {
  visualization_msgs::Marker m;
  m.header.frame_id = frame;
  m.header.stamp = stamp;
  m.ns = ns;
  m.id = 0;
  m.type = type;
  m.action = visualization_msgs::Marker::ADD;
  m.pose.orientation.w = 1.0;
  return m;
}

}  // namespace

std::string MarkerOptions::validate() const {
  if (!(node_scale_m > 0 && std::isfinite(node_scale_m))) return "marker node_scale_m must be > 0";
  if (!(edge_width_m > 0 && std::isfinite(edge_width_m))) return "marker edge_width_m must be > 0";
  if (!(loop_closure_chi2_red > 0 && std::isfinite(loop_closure_chi2_red)))
    return "marker loop_closure_chi2_red must be > 0";
  return "";
}

double visualizationPeriodSec(double rate_hz, double period_per_keyframe_sec, std::size_t keyframes) {
  return std::max(1.0 / rate_hz, period_per_keyframe_sec * static_cast<double>(keyframes));
}

std_msgs::ColorRGBA residualColour(double chi2, double chi2_red) {
  const double f = std::isfinite(chi2) ? std::clamp(chi2 / chi2_red, 0.0, 1.0) : 1.0;
  // Green to yellow over the first half, yellow to red over the second.
  const float r = static_cast<float>(std::min(1.0, 2.0 * f));
  const float g = static_cast<float>(std::min(1.0, 2.0 * (1.0 - f)));
  return rgba(r, g, 0.0f);
}

nav_msgs::Path pathFromSnapshot(const Snapshot& snapshot, const std::string& map_frame,
                                const ros::Time& stamp) {
  nav_msgs::Path path;
  path.header.frame_id = map_frame;
  path.header.stamp = stamp;
  path.poses.resize(snapshot.keyframes.size());
  for (std::size_t i = 0; i < snapshot.keyframes.size(); ++i) {
    auto& p = path.poses[i];
    p.header.frame_id = map_frame;
    p.header.stamp = snapshot.keyframes[i].stamp;
    p.pose = poseToMsg(snapshot.keyframes[i].map_T_base);
  }
  return path;
}

visualization_msgs::MarkerArray markersFromSnapshot(const Snapshot& snapshot, const std::string& map_frame,
                                                    const ros::Time& stamp, const MarkerOptions& options,
                                                    bool delete_all) {
  using visualization_msgs::Marker;
  visualization_msgs::MarkerArray out;
  if (delete_all) {
    Marker clear;
    clear.header.frame_id = map_frame;
    clear.header.stamp = stamp;
    clear.action = Marker::DELETEALL;
    out.markers.push_back(clear);
  }
  Marker nodes = baseMarker(map_frame, stamp, marker_ns::kNodes, Marker::SPHERE_LIST);
  nodes.scale.x = nodes.scale.y = nodes.scale.z = options.node_scale_m;
  nodes.color = rgba(0.2f, 0.4f, 1.0f);
  for (const auto& k : snapshot.keyframes) nodes.points.push_back(point(k.map_T_base));

  Marker odometry = baseMarker(map_frame, stamp, marker_ns::kOdometryEdges, Marker::LINE_LIST);
  odometry.scale.x = options.edge_width_m;
  odometry.color = rgba(0.6f, 0.6f, 0.6f);
  Marker loops = baseMarker(map_frame, stamp, marker_ns::kLoopClosures, Marker::LINE_LIST);
  loops.scale.x = options.edge_width_m;
  loops.color = rgba(0.0f, 1.0f, 0.0f);
  Marker down_weighted = baseMarker(map_frame, stamp, marker_ns::kDownWeightedLoopClosures, Marker::LINE_LIST);
  down_weighted.scale.x = options.edge_width_m;
  down_weighted.color = rgba(1.0f, 0.5f, 0.0f, 0.8f);
  for (const SnapshotEdge& e : snapshot.edges) {
    const geometry_msgs::Point a = point(snapshot.keyframes[e.from_index].map_T_base);
    const geometry_msgs::Point b = point(snapshot.keyframes[e.to_index].map_T_base);
    if (e.loop_closure && e.weight < toro::kRejectedWeight) {
      down_weighted.points.insert(down_weighted.points.end(), {a, b});
    } else if (e.loop_closure) {
      const std_msgs::ColorRGBA c = residualColour(e.chi2, options.loop_closure_chi2_red);
      loops.points.insert(loops.points.end(), {a, b});
      loops.colors.insert(loops.colors.end(), {c, c});
    } else if (options.draw_odometry_edges) {
      odometry.points.insert(odometry.points.end(), {a, b});
    }
  }
  Marker rejected = baseMarker(map_frame, stamp, marker_ns::kRejectedLoopClosures, Marker::LINE_LIST);
  rejected.scale.x = options.edge_width_m;
  rejected.color = rgba(1.0f, 0.0f, 1.0f, 0.6f);
  for (const SnapshotEdge& e : snapshot.rejected_edges)
    rejected.points.insert(rejected.points.end(), {point(snapshot.keyframes[e.from_index].map_T_base),
                                                   point(snapshot.keyframes[e.to_index].map_T_base)});
  // rviz rejects empty point lists with a warning; a marker with nothing to draw is deleted instead.
  for (Marker* m : {&nodes, &odometry, &loops, &down_weighted, &rejected}) {
    if (m->points.empty()) m->action = Marker::DELETE;
    out.markers.push_back(*m);
  }
  return out;
}

}  // namespace toro_ros
