// rostest client for run-time tuning (live_tuning.test): parameters changed through
// dynamic_reconfigure (set_parameters) while the node runs take effect (keyframe thresholds on the
// keyframes made from then on, exactly as a pipeline given the same change; the gate on the next
// loop closure; the tf rate), are logged change by change and land on the parameter server, and
// leave the parameters that are not live as they were.
#include <gtest/gtest.h>

#include <dynamic_reconfigure/Config.h>
#include <dynamic_reconfigure/Reconfigure.h>

#include "../pipeline/drift_scenario.h"
#include "node_test_client.h"
#include "toro_ros/MapCorrectorConfig.h"
#include "toro_ros/pipeline/pipeline.h"

using namespace toro_ros;

namespace {

using Client = toro_ros::testing::NodeTestClient;
using toro_ros::testing::Observed;

Client* client = nullptr;
const toro_ros::testing::DriftScenario scenario = toro_ros::testing::makeDriftingSquare();

// A dynamic_reconfigure client as dynparam and rqt_reconfigure are: the node's set_parameters
// service and its parameter_updates topic.  (dynamic_reconfigure::Client is not used: it decodes
// updates into a default-constructed config whose bools are uninitialised, which UBSan reports
// in the ASan stage; here every config starts from the cfg's defaults.)
class Reconfigure {
 public:
  Reconfigure()
      : updates_(ros::NodeHandle().subscribe<dynamic_reconfigure::Config>(
            "/map_corrector/parameter_updates", 1, [this](const dynamic_reconfigure::Config::ConstPtr& msg) {
              std::lock_guard<std::mutex> lock(mutex_);
              current_ = decode(*msg);
            })) {}
  // The node's configuration as last published on parameter_updates (waits in wall time).
  std::optional<MapCorrectorConfig> current() {
    Client::waitFor([&] {
      std::lock_guard<std::mutex> lock(mutex_);
      return current_.has_value();
    });
    std::lock_guard<std::mutex> lock(mutex_);
    return current_;
  }
  // Sends `config`; on success `config` is what the node answered (what it applied).
  bool set(MapCorrectorConfig& config) {
    dynamic_reconfigure::Reconfigure srv;
    config.__toMessage__(srv.request.config);
    if (!ros::service::call("/map_corrector/set_parameters", srv)) return false;
    config = decode(srv.response.config);
    return true;
  }

 private:
  static MapCorrectorConfig decode(dynamic_reconfigure::Config msg) {
    MapCorrectorConfig c = MapCorrectorConfig::__getDefault__();
    c.__fromMessage__(msg);
    return c;
  }

  ros::Subscriber updates_;
  std::mutex mutex_;  // guards current_
  std::optional<MapCorrectorConfig> current_;
};

Reconfigure* reconfigure = nullptr;

void publishAndWait(std::size_t begin, std::size_t end) {
  for (std::size_t i = begin; i < end; ++i) client->publishOdometry(scenario.odometry[i]);
  ASSERT_TRUE(Client::waitFor([&] { return client->status().odometry_messages == end; }));
}

// tf messages map -> odom received over `seconds` of wall time.
int tfCount(double seconds) {
  {
    std::lock_guard<std::mutex> lock(client->observed.mutex);
    client->observed.tf_count = 0;
  }
  std::this_thread::sleep_for(std::chrono::duration<double>(seconds));
  std::lock_guard<std::mutex> lock(client->observed.mutex);
  return client->observed.tf_count;
}

}  // namespace

TEST(LiveTuning, KeyframeThresholdsChangedLiveApplyToTheFollowingOdometry) {
  ASSERT_TRUE(client->connect());
  const std::optional<MapCorrectorConfig> start = reconfigure->current();
  ASSERT_TRUE(start.has_value());
  // The node runs config/map_corrector.yaml, whose values are the defaults.
  EXPECT_EQ(start->keyframe_distance_m, KeyframerOptions{}.distance_m);
  EXPECT_EQ(start->loop_closure_gate_confidence, 0.0);

  const std::size_t half = scenario.odometry.size() / 2;
  Pipeline expected(PipelineOptions{}), unchanged(PipelineOptions{});
  for (std::size_t i = 0; i < half; ++i) expected.handleOdometry(scenario.odometry[i]);
  publishAndWait(0, half);
  ASSERT_EQ(client->status().keyframes, expected.keyframes().size());

  MapCorrectorConfig config = *start;
  config.keyframe_distance_m = 2.0;
  config.keyframe_angle_rad = 1.5;
  ASSERT_TRUE(reconfigure->set(config));
  EXPECT_EQ(config.keyframe_distance_m, 2.0);  // the server's answer: accepted as asked
  EXPECT_TRUE(Client::waitFor([] {
    return client->logged("reconfigured keyframe_distance_m: 0.5 -> 2") &&
           client->logged("reconfigured keyframe_angle_rad: 0.35 -> 1.5");
  }));
  double on_server = 0;
  EXPECT_TRUE(ros::param::get("/map_corrector/keyframe_distance_m", on_server));
  EXPECT_EQ(on_server, 2.0);

  PipelineOptions changed;
  changed.keyframer.distance_m = 2.0;
  changed.keyframer.angle_rad = 1.5;
  ASSERT_EQ(expected.applyLiveOptions(changed), "");
  for (std::size_t i = half; i < scenario.odometry.size(); ++i) expected.handleOdometry(scenario.odometry[i]);
  for (const auto& m : scenario.odometry) unchanged.handleOdometry(m);
  publishAndWait(half, scenario.odometry.size());
  const GetStatus::Response s = client->status();
  EXPECT_EQ(s.keyframes, expected.keyframes().size());
  EXPECT_LT(s.keyframes + 10, unchanged.keyframes().size());  // the wider thresholds did matter
}

TEST(LiveTuning, GateSwitchedOnLiveRejectsTheNextWrongLoopClosure) {
  MapCorrectorConfig config = *reconfigure->current();
  config.loop_closure_gate_confidence = 0.99;
  ASSERT_TRUE(reconfigure->set(config));
  EXPECT_TRUE(
      Client::waitFor([] { return client->logged("reconfigured loop_closure_gate_confidence: 0 -> 0.99"); }));
  // The end of the run claimed 10 m from where it is, relative to the start: wrong.
  LoopClosure wrong = toro_ros::testing::trueLoopClosure(scenario, 0, scenario.odometry.size() - 1);
  wrong.from_T_to.position.x += 10.0;
  client->publishLoopClosure(wrong);
  EXPECT_TRUE(Client::waitFor([] {
    const GetStatus::Response s = client->status();
    return s.loop_closures_rejected == 1 && s.loop_closures_applied == 0;
  }));
}

TEST(LiveTuning, TfRateChangedLive) {
  // 50 Hz at the start (sim time runs with wall time here); 10 Hz after the change.
  EXPECT_GT(tfCount(1.0), 30);
  MapCorrectorConfig config = *reconfigure->current();
  config.tf_rate_hz = 10.0;
  ASSERT_TRUE(reconfigure->set(config));
  ASSERT_TRUE(Client::waitFor([] { return client->logged("reconfigured tf_rate_hz: 50 -> 10"); }));
  const int count = tfCount(2.0);
  EXPECT_GE(count, 10);
  EXPECT_LE(count, 30);
}

TEST(LiveTuning, ACorrectionGoesOutAtOnceNotAtTheNextTfTick) {
  MapCorrectorConfig config = *reconfigure->current();
  config.tf_rate_hz = 0.1;  // a tick every 10 s
  // The gate (switched on above) judges against the uncorrected map: the first revisit of a
  // drifted run would be refused; the robust support of the defaults takes it.
  config.loop_closure_gate_confidence = 0.0;
  ASSERT_TRUE(reconfigure->set(config));
  ASSERT_TRUE(Client::waitFor([] { return client->logged("reconfigured tf_rate_hz: 10 -> 0.1"); }));
  // Right after a tick the next one is 10 s away; the map has not been corrected yet (the only
  // loop closure so far was the gate's wrong one).
  const int ticks = client->observedCopy<int>([](const Observed& o) { return o.tf_count; });
  ASSERT_TRUE(client->waitObserved([&](const Observed& o) { return o.tf_count > ticks; }, 15.0));
  const auto before = client->observedCopy<geometry_msgs::Transform>(
      [](const Observed& o) { return o.map_T_odom->transform; });
  const auto sent = std::chrono::steady_clock::now();
  for (const LoopClosure& lc :
       toro_ros::testing::revisitLoopClosures(scenario, 0, scenario.odometry.size() - 1))
    client->publishLoopClosure(lc);
  const bool corrected = client->waitObserved(
      [&](const Observed& o) {
        const auto& t = o.map_T_odom->transform.translation;
        return std::hypot(t.x - before.translation.x, t.y - before.translation.y) > 0.01;
      },
      5.0);
  const double waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - sent).count();
  const GetStatus::Response st = client->status();
  EXPECT_TRUE(corrected) << "no corrected map->odom " << waited << " s after the revisit (applied "
                         << st.loop_closures_applied << ", held " << st.loop_closures_held << ", released "
                         << st.loop_closures_released << ", rejected " << st.loop_closures_rejected << ")";
  EXPECT_GE(st.loop_closures_applied, 5u);
  config.tf_rate_hz = 10.0;
  EXPECT_TRUE(reconfigure->set(config));
}

TEST(LiveTuning, ParametersThatAreNotLiveKeepTheirStartValues) {
  // live_tuning.test starts the node with map_frame corrected_map; after the changes above the
  // transforms (counted above in that frame) and the path are still in it.
  ASSERT_TRUE(client->waitObserved([](const Observed& o) { return o.path.has_value(); }));
  EXPECT_EQ(client->observedCopy<std::string>([](const Observed& o) { return o.path->header.frame_id; }),
            "corrected_map");
  std::string on_server;
  EXPECT_TRUE(ros::param::get("/map_corrector/map_frame", on_server));
  EXPECT_EQ(on_server, "corrected_map");
}

int main(int argc, char** argv) {
  ::testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "live_tuning_test_client");
  ros::NodeHandle nh;
  ros::AsyncSpinner spinner(2);
  spinner.start();
  Client c("/map_corrector", "corrected_map");
  client = &c;
  Reconfigure r;
  reconfigure = &r;
  const int result = RUN_ALL_TESTS();
  reconfigure = nullptr;
  client = nullptr;
  spinner.stop();
  return result;
}
