#include <gtest/gtest.h>

#include "toro_ros/pipeline/visualization.h"

using namespace toro_ros;
using visualization_msgs::Marker;

namespace {

Snapshot snapshot() {
  Snapshot s;
  for (int i = 0; i < 4; ++i)
    s.keyframes.push_back(
        SnapshotKeyframe{i, ros::Time(10 + i), toro::Pose3::fromRollPitchYaw(i, 2 * i, 0, 0, 0, 0)});
  s.edges = {
      {0, 1, false, 0.0}, {1, 2, false, 0.0}, {2, 3, false, 0.0}, {3, 0, true, 20.0}, {2, 0, true, 0.0}};
  return s;
}

const Marker* find(const visualization_msgs::MarkerArray& a, const std::string& ns) {
  for (const Marker& m : a.markers)
    if (m.ns == ns) return &m;
  return nullptr;
}

}  // namespace

TEST(Visualization, PathHasOnePoseAKeyframeWithItsStamp) {
  const nav_msgs::Path p = pathFromSnapshot(snapshot(), "map", ros::Time(20));
  ASSERT_EQ(p.poses.size(), 4u);
  EXPECT_EQ(p.header.frame_id, "map");
  EXPECT_EQ(p.poses[2].header.stamp, ros::Time(12));
  EXPECT_DOUBLE_EQ(p.poses[3].pose.position.y, 6.0);
}

TEST(Visualization, MarkersHaveStableNamespacesAndResidualColours) {
  const auto a = markersFromSnapshot(snapshot(), "map", ros::Time(20), MarkerOptions{}, false);
  ASSERT_EQ(a.markers.size(), 5u);  // with the (empty, so DELETE) rejected and down-weighted ones
  const Marker* rejected = find(a, marker_ns::kRejectedLoopClosures);
  ASSERT_TRUE(rejected);
  EXPECT_EQ(rejected->action, Marker::DELETE);
  const Marker* down = find(a, marker_ns::kDownWeightedLoopClosures);
  ASSERT_TRUE(down);
  EXPECT_EQ(down->action, Marker::DELETE);
  const Marker* nodes = find(a, marker_ns::kNodes);
  const Marker* odom = find(a, marker_ns::kOdometryEdges);
  const Marker* loops = find(a, marker_ns::kLoopClosures);
  ASSERT_TRUE(nodes && odom && loops);
  EXPECT_EQ(nodes->points.size(), 4u);
  EXPECT_EQ(odom->points.size(), 6u);
  ASSERT_EQ(loops->points.size(), 4u);
  ASSERT_EQ(loops->colors.size(), 4u);
  for (const Marker* m : {nodes, odom, loops}) {
    EXPECT_EQ(m->id, 0);
    EXPECT_EQ(m->action, Marker::ADD);
    EXPECT_EQ(m->header.frame_id, "map");
  }
  // chi2 20 >= red threshold 10: red; chi2 0: green.
  EXPECT_FLOAT_EQ(loops->colors[0].r, 1.0f);
  EXPECT_FLOAT_EQ(loops->colors[0].g, 0.0f);
  EXPECT_FLOAT_EQ(loops->colors[2].r, 0.0f);
  EXPECT_FLOAT_EQ(loops->colors[2].g, 1.0f);
}

TEST(Visualization, RejectedLoopClosuresHaveTheirOwnNamespaceAndColour) {
  Snapshot s = snapshot();
  s.rejected_edges.push_back(SnapshotEdge{0, 3, true, 250.0});
  const auto a = markersFromSnapshot(s, "map", ros::Time(20), MarkerOptions{}, false);
  const Marker* rejected = find(a, marker_ns::kRejectedLoopClosures);
  ASSERT_TRUE(rejected);
  EXPECT_EQ(rejected->action, Marker::ADD);
  ASSERT_EQ(rejected->points.size(), 2u);
  EXPECT_DOUBLE_EQ(rejected->points[1].y, 6.0);  // keyframe 3, as in the path
  EXPECT_FLOAT_EQ(rejected->color.r, 1.0f);
  EXPECT_FLOAT_EQ(rejected->color.g, 0.0f);
  EXPECT_FLOAT_EQ(rejected->color.b, 1.0f);
  EXPECT_EQ(find(a, marker_ns::kLoopClosures)->points.size(), 4u);  // accepted ones unchanged
}

TEST(Visualization, DownWeightedLoopClosuresAreDrawnApartInOrange) {
  Snapshot s = snapshot();
  SnapshotEdge down_weighted = s.edges[3];
  down_weighted.weight = 0.2;  // the loop closure 3 -> 0: robust weight below 0.5
  s.edges.set(3, down_weighted);
  const auto a = markersFromSnapshot(s, "map", ros::Time(20), MarkerOptions{}, false);
  const Marker* down = find(a, marker_ns::kDownWeightedLoopClosures);
  const Marker* loops = find(a, marker_ns::kLoopClosures);
  ASSERT_TRUE(down && loops);
  EXPECT_EQ(down->action, Marker::ADD);
  ASSERT_EQ(down->points.size(), 2u);
  EXPECT_DOUBLE_EQ(down->points[0].y, 6.0);  // keyframe 3
  EXPECT_DOUBLE_EQ(down->points[1].y, 0.0);  // keyframe 0
  EXPECT_FLOAT_EQ(down->color.r, 1.0f);
  EXPECT_FLOAT_EQ(down->color.g, 0.5f);
  EXPECT_FLOAT_EQ(down->color.b, 0.0f);
  EXPECT_EQ(loops->points.size(), 2u);  // only the one with full weight stays among the accepted
}

TEST(Visualization, DeleteAllComesFirstAfterAReset) {
  const auto a = markersFromSnapshot(snapshot(), "map", ros::Time(20), MarkerOptions{}, true);
  ASSERT_EQ(a.markers.size(), 6u);
  EXPECT_EQ(a.markers[0].action, Marker::DELETEALL);
}

TEST(Visualization, EmptySnapshotDeletesInsteadOfDrawingNothing) {
  const auto a = markersFromSnapshot(Snapshot{}, "map", ros::Time(20), MarkerOptions{}, false);
  for (const Marker& m : a.markers) EXPECT_EQ(m.action, Marker::DELETE);
}

TEST(Visualization, ResidualColourRamp) {
  EXPECT_FLOAT_EQ(residualColour(5.0, 10.0).r, 1.0f);  // half way: yellow
  EXPECT_FLOAT_EQ(residualColour(5.0, 10.0).g, 1.0f);
  EXPECT_FLOAT_EQ(residualColour(std::nan(""), 10.0).r, 1.0f);
}

TEST(Visualization, LargeGraphsArePublishedLessOften) {
  // 2 Hz and 1e-4 s per keyframe: the rate's 0.5 s up to 5,000 keyframes, then linear.
  EXPECT_DOUBLE_EQ(visualizationPeriodSec(2.0, 1e-4, 0), 0.5);
  EXPECT_DOUBLE_EQ(visualizationPeriodSec(2.0, 1e-4, 5000), 0.5);
  EXPECT_DOUBLE_EQ(visualizationPeriodSec(2.0, 1e-4, 20000), 2.0);
  EXPECT_DOUBLE_EQ(visualizationPeriodSec(2.0, 1e-4, 100000), 10.0);
  EXPECT_DOUBLE_EQ(visualizationPeriodSec(10.0, 0.0, 100000), 0.1);  // 0: the rate alone
}
