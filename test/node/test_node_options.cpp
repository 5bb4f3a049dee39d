// The shipped config against the options loader: every key known, every known key documented,
// unknown keys and wrong types reported.  No master needed.
#include <cctype>
#include <fstream>
#include <iterator>
#include <set>
#include <sstream>

#include <gtest/gtest.h>

#include "toro_ros/node/live_options.h"
#include "toro_ros/node/node_options.h"
#include "toro_ros/offline/flat_yaml.h"

using namespace toro_ros;
using toro_ros::offline::readFlatYaml;

namespace {

const std::string kConfig = std::string(TORO_SOURCE_DIR) + "/config/map_corrector.yaml";

}  // namespace

TEST(NodeOptions, ShippedConfigHasExactlyTheKnownKeys) {
  const XmlRpc::XmlRpcValue params = readFlatYaml(kConfig);
  OptionsReport report;
  loadNodeOptions(params, &report);
  EXPECT_TRUE(report.unknown_keys.empty()) << report.unknown_keys.front();
  EXPECT_TRUE(report.errors.empty()) << report.errors.front();
  for (const std::string& key : knownParameterKeys())
    EXPECT_TRUE(XmlRpc::XmlRpcValue(params).hasMember(key)) << key << " is not in " << kConfig;
}

TEST(NodeOptions, ShippedConfigValuesAreTheDefaults) {
  OptionsReport report;
  const NodeOptions loaded = loadNodeOptions(readFlatYaml(kConfig), &report);
  const NodeOptions defaults;
  EXPECT_EQ(loaded.map_frame, defaults.map_frame);
  EXPECT_EQ(loaded.tf_rate_hz, defaults.tf_rate_hz);
  EXPECT_EQ(loaded.visualization_period_per_keyframe_sec, defaults.visualization_period_per_keyframe_sec);
  EXPECT_EQ(loaded.pipeline.keyframer.distance_m, defaults.pipeline.keyframer.distance_m);
  EXPECT_EQ(loaded.pipeline.keyframer.covariance_mode, defaults.pipeline.keyframer.covariance_mode);
  EXPECT_EQ(loaded.pipeline.matcher.max_pending, defaults.pipeline.matcher.max_pending);
  EXPECT_EQ(loaded.pipeline.matcher.create_keyframes, defaults.pipeline.matcher.create_keyframes);
  EXPECT_EQ(loaded.pipeline.loop_closure_default_stddev.rotation_rad,
            defaults.pipeline.loop_closure_default_stddev.rotation_rad);
  EXPECT_EQ(loaded.pipeline.optimization.full_every_keyframes,
            defaults.pipeline.optimization.full_every_keyframes);
  EXPECT_EQ(loaded.markers.draw_odometry_edges, defaults.markers.draw_odometry_edges);
  // Every value line of the report says "(default)" only when the key is missing: none here.
  for (const std::string& line : report.values) EXPECT_EQ(line.find("(default)"), std::string::npos) << line;
}

TEST(NodeOptions, UnknownKeysAreReported) {
  XmlRpc::XmlRpcValue params;
  params["keyframe_distance_m"] = 1.5;
  params["keyframe_distnce_m"] = 2.0;  // typo
  OptionsReport report;
  const NodeOptions o = loadNodeOptions(params, &report);
  ASSERT_EQ(report.unknown_keys.size(), 1u);
  EXPECT_EQ(report.unknown_keys[0], "keyframe_distnce_m");
  EXPECT_TRUE(report.errors.empty());
  EXPECT_EQ(o.pipeline.keyframer.distance_m, 1.5);
}

TEST(NodeOptions, IntegersAreAcceptedForDoubles) {
  XmlRpc::XmlRpcValue params;
  params["tf_rate_hz"] = 20;
  OptionsReport report;
  EXPECT_EQ(loadNodeOptions(params, &report).tf_rate_hz, 20.0);
  EXPECT_TRUE(report.errors.empty());
}

TEST(NodeOptions, WrongTypesAndInvalidValuesAreErrorsNamingTheKey) {
  XmlRpc::XmlRpcValue params;
  params["queue_size"] = std::string("big");
  params["odometry_covariance_mode"] = std::string("guess");
  OptionsReport report;
  loadNodeOptions(params, &report);
  ASSERT_EQ(report.errors.size(), 2u);
  EXPECT_NE(report.errors[0].find("queue_size"), std::string::npos);
  EXPECT_NE(report.errors[1].find("odometry_covariance_mode"), std::string::npos);

  XmlRpc::XmlRpcValue bad_link;
  bad_link["resume_link"] = std::string("sideways");
  bad_link["autosave_period_sec"] = 0.0;
  OptionsReport r1;
  loadNodeOptions(bad_link, &r1);
  ASSERT_EQ(r1.errors.size(), 1u);  // validation runs only once the keys themselves are readable
  EXPECT_NE(r1.errors[0].find("resume_link: expected continue or last_pose, got 'sideways'"), std::string::npos);
  bad_link["resume_link"] = std::string("last_pose");
  OptionsReport r3;
  EXPECT_EQ(loadNodeOptions(bad_link, &r3).pipeline.persistence.resume_link, ResumeLink::kLastPose);
  ASSERT_EQ(r3.errors.size(), 1u);
  EXPECT_NE(r3.errors[0].find("autosave_period_sec must be > 0"), std::string::npos) << r3.errors[0];

  XmlRpc::XmlRpcValue bad_range;
  bad_range["keyframe_angle_rad"] = -1.0;
  OptionsReport r2;
  loadNodeOptions(bad_range, &r2);
  ASSERT_EQ(r2.errors.size(), 1u);
  EXPECT_NE(r2.errors[0].find("angle_rad"), std::string::npos);

  XmlRpc::XmlRpcValue bad_period;
  bad_period["visualization_period_per_keyframe_sec"] = -1e-4;
  OptionsReport r4;
  loadNodeOptions(bad_period, &r4);
  ASSERT_EQ(r4.errors.size(), 1u);
  EXPECT_NE(r4.errors[0].find("visualization_period_per_keyframe_sec must be >= 0"), std::string::npos);
  bad_period["visualization_period_per_keyframe_sec"] = 0.0;  // 0: the rate alone
  OptionsReport r5;
  EXPECT_EQ(loadNodeOptions(bad_period, &r5).visualization_period_per_keyframe_sec, 0.0);
  EXPECT_TRUE(r5.errors.empty());
}

TEST(NodeOptions, FinishThreadsDefaultIsOneAndNegativeCountsAreErrors) {
  OptionsReport defaults;
  EXPECT_EQ(loadNodeOptions(XmlRpc::XmlRpcValue(), &defaults).finish_threads, 1);
  XmlRpc::XmlRpcValue params;
  params["finish_threads"] = 0;  // the libraries' own
  OptionsReport zero;
  EXPECT_EQ(loadNodeOptions(params, &zero).finish_threads, 0);
  EXPECT_TRUE(zero.errors.empty());
  params["finish_threads"] = -1;
  OptionsReport negative;
  loadNodeOptions(params, &negative);
  ASSERT_EQ(negative.errors.size(), 1u);
  EXPECT_NE(negative.errors[0].find("finish_threads: solver threads must be in [0, 1024]"), std::string::npos)
      << negative.errors[0];
  params["finish_threads"] = 1.5;
  OptionsReport fraction;
  loadNodeOptions(params, &fraction);
  ASSERT_EQ(fraction.errors.size(), 1u);
  EXPECT_NE(fraction.errors[0].find("finish_threads: expected an integer"), std::string::npos) << fraction.errors[0];
}

// The message and service definitions document the node's interface in their comments: every
// "~name" they mention must be a parameter, topic or service the node has (they once named
// ~loop_closure/stamp_tolerance_sec and ~optimization/full_iterations, which never existed).
TEST(NodeOptions, EveryPrivateNameInTheMessageAndServiceCommentsExists) {
  std::set<std::string> names = knownParameterKeys();
  for (const char* n : {"path", "graph_markers", "graph", "pose", "optimize", "pause", "resume", "reset",
                        "save_graph", "load_graph", "get_status", "set_parameters"})
    names.insert(n);
  std::size_t mentioned = 0;
  for (const char* file : {"msg/LoopClosure.msg", "msg/PoseGraph.msg", "msg/PoseGraphNode.msg", "msg/PoseGraphEdge.msg",
                           "srv/Optimize.srv", "srv/GraphFile.srv", "srv/GetStatus.srv"}) {
    std::ifstream in(std::string(TORO_SOURCE_DIR) + "/" + file);
    ASSERT_TRUE(in.good()) << file;
    const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    for (std::size_t at = text.find('~'); at != std::string::npos; at = text.find('~', at + 1)) {
      if (at + 1 < text.size() && text[at + 1] == '/') continue;  // a home directory, "~/.ros"
      std::size_t end = at + 1;
      while (end < text.size() && (std::isalnum(static_cast<unsigned char>(text[end])) || text[end] == '_' || text[end] == '/'))
        ++end;
      const std::string name = text.substr(at + 1, end - at - 1);
      ++mentioned;
      EXPECT_TRUE(names.count(name)) << file << " names ~" << name << ", which the node does not have";
    }
  }
  EXPECT_GE(mentioned, 8u);
}

// README.md's "Node API" lists the parameters by group: every known key, and nothing else, and
// marks as "live" exactly those of cfg/MapCorrector.cfg.
TEST(NodeOptions, TheReadmeNodeApiListsEveryParameter) {
  std::ifstream in(std::string(TORO_SOURCE_DIR) + "/README.md");
  ASSERT_TRUE(in.good());
  const std::string readme((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::size_t begin = readme.find("\n## Node API");
  ASSERT_NE(begin, std::string::npos);
  const std::size_t table = readme.find("| group | parameter | default | live |", begin);
  ASSERT_NE(table, std::string::npos);
  const std::size_t end = readme.find("\n\n", table);
  std::set<std::string> listed, marked_live;
  std::istringstream rows(readme.substr(table, end - table));
  std::string row;
  while (std::getline(rows, row)) {
    // "| group | `key` ... | default | live |": the first back-quoted word of the second cell.
    const std::size_t cell = row.find('|', 1);
    const std::size_t open = row.find('`', cell), close = row.find('`', open + 1);
    if (cell == std::string::npos || open == std::string::npos || close == std::string::npos) continue;
    const std::string key = row.substr(open + 1, close - open - 1);
    listed.insert(key);
    const std::string live_cell = " live |";
    if (row.size() >= live_cell.size() && row.compare(row.size() - live_cell.size(), live_cell.size(), live_cell) == 0)
      marked_live.insert(key);
  }
  EXPECT_EQ(marked_live, liveParameterKeys());
  const std::set<std::string> known = knownParameterKeys();
  for (const std::string& key : known) EXPECT_TRUE(listed.count(key)) << key << " is not in README.md's Node API";
  for (const std::string& key : listed) EXPECT_TRUE(known.count(key)) << "README.md's Node API lists " << key;
}
