// rostest client for map_corrector_node under simulated time.  It publishes /clock itself, the
// drifting square of test/pipeline/drift_scenario.h and loop closures, and checks what the node
// publishes and answers.  The tests run in declaration order and share the node's state.
#include <unistd.h>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include <gtest/gtest.h>

#include "../pipeline/drift_scenario.h"
#include "node_test_client.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/pipeline/persistence.h"
#include "toro_ros/pipeline/pipeline.h"

using namespace toro_ros;

namespace {

using Client = toro_ros::testing::NodeTestClient;
using toro_ros::testing::Observed;

Client* client = nullptr;
const toro_ros::testing::DriftScenario scenario = toro_ros::testing::makeDriftingSquare();
std::string temp_dir;

toro::Pose3 poseOf(const geometry_msgs::Transform& t) {
  return toro::Pose3(toro::Quaternion(t.rotation.w, t.rotation.x, t.rotation.y, t.rotation.z),
                     toro::Vector3(t.translation.x, t.translation.y, t.translation.z));
}

double newestError(const geometry_msgs::Transform& map_T_odom) {
  const toro::Pose3 odom_T_base = poseFromMsg(scenario.odometry.back().pose.pose);
  return ((poseOf(map_T_odom) * odom_T_base).translation() - scenario.truth.back().translation()).norm();
}

std::uint64_t refusedCount(const GetStatus::Response& s, const std::string& reason) {
  for (std::size_t i = 0; i < s.refused_reasons.size(); ++i)
    if (s.refused_reasons[i] == reason) return s.refused_counts[i];
  return 0;
}

}  // namespace

TEST(MapCorrector, KeyframesFromOdometryMatchThePipeline) {
  ASSERT_TRUE(client->connect());
  for (const auto& m : scenario.odometry) client->publishOdometry(m);
  const std::size_t n = scenario.odometry.size();
  ASSERT_TRUE(Client::waitFor([&] { return client->status().odometry_messages == n; }));
  // The node runs config/map_corrector.yaml, whose values are the defaults (test_node_options).
  Pipeline expected(PipelineOptions{});
  for (const auto& m : scenario.odometry) expected.handleOdometry(m);
  const GetStatus::Response s = client->status();
  EXPECT_EQ(s.keyframes, expected.keyframes().size());
  EXPECT_EQ(s.constraints, expected.keyframes().size() - 1);
  EXPECT_GT(s.keyframes, 20u);
  EXPECT_EQ(s.queue_dropped, 0u);
}

TEST(MapCorrector, LoopClosureCorrectsMapToOdomOnTf) {
  // Before the loop closure map->odom is the identity, and the newest pose carries the full drift.
  ASSERT_TRUE(client->waitObserved([](const Observed& o) { return o.map_T_odom.has_value(); }));
  double raw_error = 0;
  {
    std::lock_guard<std::mutex> lock(client->observed.mutex);
    raw_error = newestError(client->observed.map_T_odom->transform);
    // Simulated time: stamped from /clock (about 100..200 s), not wall time, and ahead of it.
    const double stamp = client->observed.map_T_odom->header.stamp.toSec();
    EXPECT_GT(stamp, 99.0);
    client->observed.max_ahead = -1e9;
    client->observed.tf_count = 0;
  }
  // Stamped transform_tolerance_sec (0.1 s) ahead of the node's clock, which trails ours by the
  // transport of /clock and of the transform: over 20 transforms the smallest lag is a few ms
  // (the largest "ahead" close to 0.1 s), never negative.
  ASSERT_TRUE(client->waitObserved([](const Observed& o) { return o.tf_count >= 20; }));
  {
    std::lock_guard<std::mutex> lock(client->observed.mutex);
    EXPECT_GT(client->observed.max_ahead, 0.05);
    EXPECT_LE(client->observed.max_ahead, 0.1 + 1e-6);
  }
  ASSERT_GT(raw_error, 1.0);
  for (const LoopClosure& lc : toro_ros::testing::revisitLoopClosures(scenario, 0, scenario.odometry.size() - 1))
    client->publishLoopClosure(lc);
  ASSERT_TRUE(Client::waitFor([&] { return client->status().loop_closures_applied == 5; }));
  double corrected = raw_error;
  EXPECT_TRUE(client->waitObserved([&](const Observed& o) {
    corrected = newestError(o.map_T_odom->transform);
    return corrected < 0.1 * raw_error;
  })) << "raw "
      << raw_error << " corrected " << corrected;
}

TEST(MapCorrector, PathAndMarkersShowTheCorrectedGraph) {
  const std::size_t keyframes = client->status().keyframes;
  EXPECT_TRUE(client->waitObserved([&](const Observed& o) {
    if (!o.path || o.path->poses.size() != keyframes || !o.markers) return false;
    for (const auto& m : o.markers->markers)
      if (m.ns == "loop_closures" && m.points.size() == 10) return true;  // the revisit's five lines
    return false;
  }));
  std::lock_guard<std::mutex> lock(client->observed.mutex);
  ASSERT_TRUE(client->observed.path.has_value());
  EXPECT_EQ(client->observed.path->header.frame_id, "map");
  const auto& last = client->observed.path->poses.back().pose.position;
  const toro::Vector3 truth = scenario.truth.back().translation();
  EXPECT_LT(std::hypot(last.x - truth.x(), last.y - truth.y()), 0.3);
  for (const auto& m : client->observed.markers->markers) {
    EXPECT_EQ(m.header.frame_id, "map");
    EXPECT_EQ(m.id, 0);
    if (m.ns == "keyframes") {
      EXPECT_EQ(m.points.size(), keyframes);
    }
    if (m.ns == "odometry_edges") {
      EXPECT_EQ(m.points.size(), 2 * (keyframes - 1));
    }
  }
}

TEST(MapCorrector, DiagnosticsReportQueueGraphSizeAndTheUnknownParameter) {
  const std::string keyframes = std::to_string(client->status().keyframes);
  EXPECT_TRUE(client->waitObserved([&](const Observed& o) {
    if (!o.diagnostics) return false;
    bool has_queue = false, has_keyframes = false, names_typo = false;
    for (const auto& kv : o.diagnostics->values) {
      has_queue |= kv.key == "queue length";
      has_keyframes |= kv.key == "keyframes" && kv.value == keyframes;
      names_typo |= kv.key == "unknown parameters" && kv.value == "keyframe_distnce_m";
    }
    // The test launch file sets the misspelt keyframe_distnce_m: a warning, not an error.
    return has_queue && has_keyframes && names_typo &&
           o.diagnostics->level == diagnostic_msgs::DiagnosticStatus::WARN;
  }));
}

TEST(MapCorrector, OptimizePauseResumeStatus) {
  Optimize srv;
  srv.request.iterations = 10;
  srv.request.mode = "full";
  ASSERT_TRUE(ros::service::call("/map_corrector/optimize", srv));
  EXPECT_TRUE(srv.response.success) << srv.response.message;
  EXPECT_LE(srv.response.chi2_after, srv.response.chi2_before * (1 + 1e-9));
  EXPECT_GE(srv.response.time_sec, 0.0);
  EXPECT_NEAR(client->status().last_chi2, srv.response.chi2_after, 1e-9 * (1 + srv.response.chi2_after));
  srv.request.mode = "finish";
  srv.request.iterations = 0;
  ASSERT_TRUE(ros::service::call("/map_corrector/optimize", srv));
  EXPECT_TRUE(srv.response.success) << srv.response.message;
  EXPECT_LE(srv.response.chi2_after, srv.response.chi2_before);
  srv.request.mode = "nonsense";
  ASSERT_TRUE(ros::service::call("/map_corrector/optimize", srv));
  EXPECT_FALSE(srv.response.success);
  EXPECT_NE(srv.response.message.find("nonsense"), std::string::npos);

  ASSERT_TRUE(client->trigger("pause"));
  EXPECT_TRUE(client->status().paused);
  ASSERT_TRUE(client->trigger("resume"));
  EXPECT_FALSE(client->status().paused);
}

TEST(MapCorrector, SaveResetLoadGivesTheSameGraph) {
  const std::string first = temp_dir + "/first.g2o", second = temp_dir + "/second.g2o";
  const GetStatus::Response before = client->status();
  const GraphFile::Response saved = client->graphFile("save_graph", first);
  ASSERT_TRUE(saved.success) << saved.message;

  ASSERT_TRUE(client->trigger("reset"));
  EXPECT_EQ(client->status().keyframes, 0u);
  EXPECT_TRUE(client->waitObserved([](const Observed& o) { return o.saw_delete_all; }));

  EXPECT_FALSE(client->graphFile("load_graph", temp_dir + "/missing.g2o").success);
  const GraphFile::Response loaded = client->graphFile("load_graph", first);
  ASSERT_TRUE(loaded.success) << loaded.message;
  const GetStatus::Response after = client->status();
  EXPECT_EQ(after.keyframes, before.keyframes);
  EXPECT_EQ(after.constraints, before.constraints);
  ASSERT_TRUE(client->graphFile("save_graph", second).success);
  // Same graph: same ids, poses and constraints (to rounding: a read re-normalises quaternions).
  const toro::PoseGraph a = toro::readGraph(first), b = toro::readGraph(second);
  ASSERT_EQ(a.numNodes(), b.numNodes());
  ASSERT_EQ(a.numConstraints(), b.numConstraints());
  for (std::size_t i = 0; i < a.numNodes(); ++i) {
    EXPECT_EQ(a.node(i).id, b.node(i).id);
    EXPECT_LT((a.node(i).pose.translation() - b.node(i).pose.translation()).norm(), 1e-12);
    EXPECT_LT(toro::relativePose(a.node(i).pose, b.node(i).pose).angle(), 1e-12);
  }
  for (std::size_t c = 0; c < a.numConstraints(); ++c) {
    EXPECT_EQ(a.constraints()[c].from, b.constraints()[c].from);
    EXPECT_EQ(a.constraints()[c].to, b.constraints()[c].to);
    EXPECT_LT((a.constraints()[c].information - b.constraints()[c].information).cwiseAbs().maxCoeff(), 1e-9);
  }
  const Sidecar sa = readSidecar(sidecarPath(first)), sb = readSidecar(sidecarPath(second));
  ASSERT_EQ(sa.keyframes.size(), sb.keyframes.size());
  for (std::size_t i = 0; i < sa.keyframes.size(); ++i)
    EXPECT_EQ(sa.keyframes[i].stamp, sb.keyframes[i].stamp);
  EXPECT_EQ(sa.loop_closures, sb.loop_closures);
}

// ~save_graph / ~load_graph answer anyone on the ROS network: names are confined to the node's
// graph_directory (pipeline/graph_directory.h; every case in detail in test_graph_directory).
TEST(MapCorrector, FileServicesAreConfinedToTheGraphDirectory) {
  namespace fs = std::filesystem;
  const GetStatus::Response before = client->status();
  ASSERT_GT(before.keyframes, 0u);
  const auto slurp = [](const fs::path& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  };
  char outside_template[] = "/tmp/toro_node_outside_XXXXXX";
  ASSERT_NE(mkdtemp(outside_template), nullptr);
  const fs::path outside = outside_template, dir = temp_dir;
  const std::string victim_text = "export PATH=/usr/bin\n# a file the node must not replace\n";
  std::ofstream(outside / "victim.g2o") << victim_text;
  std::ofstream(dir / "notes.g2o") << victim_text;
  fs::create_symlink(outside, dir / "out_dir");
  fs::create_symlink(outside / "victim.g2o", dir / "out_file.g2o");

  const auto refused = [&](const std::string& service, const std::string& name, const std::string& why) {
    const GraphFile::Response r = client->graphFile(service, name);
    EXPECT_FALSE(r.success) << service << " " << name;
    EXPECT_NE(r.message.find(why), std::string::npos) << service << " " << name << ": " << r.message;
    return r.message;
  };
  refused("save_graph", (outside / "x.g2o").string(), "is outside graph_directory " + temp_dir);
  refused("save_graph", "../x.g2o", "is outside graph_directory");
  refused("save_graph", "out_dir/x.g2o", "leads outside graph_directory " + temp_dir + " through a symbolic link");
  refused("save_graph", "out_file.g2o", "through a symbolic link");
  refused("save_graph", "notes.g2o", "refusing to replace 'notes.g2o'");
  refused("save_graph", "", "no file name given");
  refused("save_graph", "map.txt", "is not a graph file name");
  EXPECT_EQ(slurp(outside / "victim.g2o"), victim_text);
  EXPECT_EQ(slurp(dir / "notes.g2o"), victim_text);
  EXPECT_FALSE(fs::exists(dir / "notes.g2o.stamps"));
  EXPECT_FALSE(fs::exists(dir.parent_path() / "x.g2o"));
  std::set<std::string> outside_files;
  for (const auto& e : fs::directory_iterator(outside)) outside_files.insert(e.path().filename().string());
  EXPECT_EQ(outside_files, std::set<std::string>{"victim.g2o"});

  // /etc/passwd: refused, and no answer holds any of its content (nor of a copy inside).
  const std::string passwd = slurp("/etc/passwd");
  const std::string user = passwd.substr(0, passwd.find(':'));
  ASSERT_FALSE(user.empty());
  fs::create_symlink("/etc/passwd", dir / "users.g2o");
  std::ofstream(dir / "passwd_copy.g2o") << passwd;
  for (const std::string& m : {refused("load_graph", "/etc/passwd", "is outside graph_directory"),
                               refused("load_graph", "../../../../../../etc/passwd", "is outside graph_directory"),
                               refused("load_graph", "/etc/passwd.g2o", "is outside graph_directory"),
                               refused("load_graph", "users.g2o", "through a symbolic link"),
                               refused("load_graph", "passwd_copy.g2o", "passwd_copy.g2o:1: the line does not start with a tag")}) {
    EXPECT_EQ(m.find(user + ":"), std::string::npos) << m;
    EXPECT_EQ(m.find("/bin/"), std::string::npos) << m;
  }
  EXPECT_EQ(client->status().keyframes, before.keyframes);  // refusals change nothing

  // A name relative to the directory: saved there, loaded back.
  const GraphFile::Response saved = client->graphFile("save_graph", "relative map.g2o");
  ASSERT_TRUE(saved.success) << saved.message;
  EXPECT_NE(saved.message.find((dir / "relative map.g2o").string()), std::string::npos) << saved.message;
  EXPECT_EQ(toro::readGraph((dir / "relative map.g2o").string()).numNodes(), before.keyframes);
  EXPECT_TRUE(fs::exists(dir / "relative map.g2o.stamps"));
  const GraphFile::Response loaded = client->graphFile("load_graph", "relative map.g2o");
  ASSERT_TRUE(loaded.success) << loaded.message;
  EXPECT_EQ(client->status().keyframes, before.keyframes);
  EXPECT_EQ(client->status().constraints, before.constraints);
  fs::remove_all(outside);
}

TEST(MapCorrector, UnknownStampRefusedFutureStampAppliedWhenOdometryArrives) {
  const GetStatus::Response before = client->status();
  LoopClosure unknown = toro_ros::testing::trueLoopClosure(scenario, 0, 10);
  unknown.stamp_from = ros::Time(20.0);
  // Found now, after the graph loaded above (one sent before it would be refused as already in it).
  unknown.header.stamp = scenario.odometry.back().header.stamp + ros::Duration(0.5);
  client->publishLoopClosure(unknown);
  ASSERT_TRUE(Client::waitFor(
      [&] { return client->status().loop_closures_refused == before.loop_closures_refused + 1; }));
  const std::uint64_t refused = refusedCount(client->status(), "loop closure: no keyframe within tolerance");
  EXPECT_EQ(refused, refusedCount(before, "loop closure: no keyframe within tolerance") + 1);
  // Diagnostics carry the same count under "refused: <reason>".
  EXPECT_TRUE(client->waitObserved([&](const Observed& o) {
    if (!o.diagnostics) return false;
    for (const auto& kv : o.diagnostics->values)
      if (kv.key == "refused: loop closure: no keyframe within tolerance") return kv.value == std::to_string(refused);
    return false;
  }));

  // Drive on from the end of the scenario (the loaded graph ends there) for 3 more seconds.
  const nav_msgs::Odometry& end = scenario.odometry.back();
  const toro::Pose3 end_pose = poseFromMsg(end.pose.pose);
  std::vector<nav_msgs::Odometry> more;
  for (int i = 1; i <= 30; ++i)
    more.push_back(
        toro_ros::testing::odometryMsg(end.header.stamp + ros::Duration(0.1 * i),
                                       end_pose * toro::Pose3::fromRollPitchYaw(0.1 * i, 0, 0, 0, 0, 0)));
  LoopClosure future;
  future.id_from = future.id_to = -1;
  future.stamp_from = scenario.odometry.front().header.stamp;
  future.stamp_to = more[19].header.stamp;  // 2 s after the newest odometry
  future.from_T_to = poseToMsg(toro::relativePose(scenario.truth.front(), scenario.truth.back()) *
                               toro::Pose3::fromRollPitchYaw(2.0, 0, 0, 0, 0, 0));
  client->publishLoopClosure(future);
  ASSERT_TRUE(Client::waitFor([&] { return client->status().loop_closures_pending == 1; }));
  EXPECT_EQ(client->status().loop_closures_applied, before.loop_closures_applied);
  for (const auto& m : more) client->publishOdometry(m);
  EXPECT_TRUE(Client::waitFor([&] {
    const auto s = client->status();
    return s.loop_closures_pending == 0 && s.loop_closures_applied == before.loop_closures_applied + 1;
  }));
}

TEST(MapCorrector, TimeJumpBackResetsTheGraph) {
  const GetStatus::Response before = client->status();
  client->publishOdometry(toro_ros::testing::odometryMsg(ros::Time(30.0), toro::Pose3()));
  EXPECT_TRUE(
      Client::waitFor([&] { return client->status().time_jump_resets == before.time_jump_resets + 1; }));
  EXPECT_EQ(client->status().keyframes, 1u);
}

TEST(MapCorrector, ServicesOnAnEmptyGraphBadPathsAndWrongFramesAnswerWithTheReason) {
  ASSERT_TRUE(client->trigger("reset"));
  ASSERT_EQ(client->status().keyframes, 0u);
  Optimize opt;
  opt.request.iterations = 5;
  opt.request.mode = "full";
  ASSERT_TRUE(ros::service::call("/map_corrector/optimize", opt));
  EXPECT_FALSE(opt.response.success);
  EXPECT_NE(opt.response.message.find("nothing to optimise"), std::string::npos) << opt.response.message;
  const GraphFile::Response empty = client->graphFile("save_graph", temp_dir + "/empty.g2o");
  EXPECT_FALSE(empty.success);
  EXPECT_NE(empty.message.find("empty"), std::string::npos) << empty.message;

  // Two keyframes, then a save into a directory that does not exist and a load of garbage.
  const ros::Time t0(400.0);
  client->publishOdometry(toro_ros::testing::odometryMsg(t0, toro::Pose3()));
  client->publishOdometry(toro_ros::testing::odometryMsg(t0 + ros::Duration(1.0), toro::Pose3::fromRollPitchYaw(2, 0, 0, 0, 0, 0)));
  ASSERT_TRUE(Client::waitFor([&] { return client->status().keyframes == 2; }));
  const GraphFile::Response bad_save = client->graphFile("save_graph", "no_such_dir/map.g2o");
  EXPECT_FALSE(bad_save.success);
  EXPECT_NE(bad_save.message.find("there is no directory no_such_dir"), std::string::npos) << bad_save.message;
  const std::string garbage = temp_dir + "/garbage.g2o";
  std::ofstream(garbage) << "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nEDGE_SE3:QUAT 0 1 oops\n";
  const GraphFile::Response bad_load = client->graphFile("load_graph", garbage);
  EXPECT_FALSE(bad_load.success);
  EXPECT_NE(bad_load.message.find(garbage + ":2"), std::string::npos) << bad_load.message;
  EXPECT_EQ(client->status().keyframes, 2u);  // a failed load changes nothing

  // Odometry in a frame other than odom_frame is refused and counted, in ~get_status and diagnostics.
  const GetStatus::Response before = client->status();
  nav_msgs::Odometry wrong = toro_ros::testing::odometryMsg(t0 + ros::Duration(2.0), toro::Pose3::fromRollPitchYaw(4, 0, 0, 0, 0, 0));
  wrong.header.frame_id = "wheel_odom";
  client->publishOdometry(wrong);
  ASSERT_TRUE(Client::waitFor([&] { return refusedCount(client->status(), "odometry: wrong frame") == refusedCount(before, "odometry: wrong frame") + 1; }));
  EXPECT_EQ(client->status().keyframes, 2u);
  const std::string count = std::to_string(refusedCount(client->status(), "odometry: wrong frame"));
  EXPECT_TRUE(client->waitObserved([&](const Observed& o) {
    if (!o.diagnostics) return false;
    for (const auto& kv : o.diagnostics->values)
      if (kv.key == "refused: odometry: wrong frame") return kv.value == count;
    return false;
  }));
}

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "map_corrector_test_client");
  ros::NodeHandle nh;
  ros::AsyncSpinner spinner(2);
  spinner.start();
  // The node's graph_directory (map_corrector.test): the file services' names go there.
  if (!ros::param::get("/map_corrector/graph_directory", temp_dir) || temp_dir.empty()) return 1;
  std::filesystem::create_directories(temp_dir);
  Client c;
  client = &c;
  const int result = RUN_ALL_TESTS();
  std::filesystem::remove_all(temp_dir);
  client = nullptr;
  spinner.stop();
  return result;
}
