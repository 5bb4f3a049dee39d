// rostest client for kill_resume.test: the "nothing lost" test with the real node process.
// The client plays the bundled sample itself (/clock, odom, loop_closure in bag order, in chunks
// it lets the node catch up with), runs map_corrector_node as a child process with autosave_path
// = load_path, kills it with SIGKILL part-way, starts it again on the autosave, finishes the
// replay, and compares the final graph with an uninterrupted toro_offline run of the same bag and
// configuration:
//   - what is missing lies between the last autosave and the kill (at most one autosave period
//     of message time, plus the keyframe that was being made), nothing else;
//   - the keyframes both have sit in the same place (the kill only cost the missing stretch),
//   - both are as close to the truth.
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>

#include <gtest/gtest.h>
#include <nav_msgs/Odometry.h>
#include <ros/ros.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <rosgraph_msgs/Clock.h>

#include "toro_ros/GetStatus.h"
#include "toro_ros/GraphFile.h"
#include "toro_ros/LoopClosure.h"
#include "toro_ros/Optimize.h"
#include "toro_ros/core/graph_io.h"
#include "toro_ros/node/names.h"
#include "toro_ros/offline/flat_yaml.h"
#include "toro_ros/offline/offline_runner.h"
#include "toro_ros/offline/scoring.h"
#include "toro_ros/pipeline/persistence.h"

namespace toro_ros {
namespace offline {
namespace {

namespace fs = std::filesystem;

constexpr const char* kNodeName = "/kill_resume_corrector";
constexpr double kAutosavePeriodSec = 5.0;  // message time; the sample lasts about 36 s
constexpr double kKillFraction = 0.6;       // of the bag's messages
constexpr std::size_t kChunk = 1;  // messages published before waiting for the node (and its finish)

std::string sampleDir() {
  std::string dir;
  ros::param::get("~sample_dir", dir);
  return dir.empty() ? TORO_SAMPLE_DIR : dir;
}

bool waitWall(const std::function<bool()>& done, double seconds) {
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(seconds);
  while (!done()) {
    if (ros::WallTime::now() > deadline || !ros::ok()) return false;
    ros::WallDuration(0.02).sleep();
  }
  return true;
}

template <class S>
bool call(const std::string& service, S& srv) {
  return ros::service::call(std::string(kNodeName) + "/" + service, srv);
}

std::optional<GetStatus::Response> status() {
  GetStatus srv;
  if (!call(names::kGetStatusService, srv)) return std::nullopt;
  return srv.response;
}

// The node as a child process; its output goes to `log`.
class NodeProcess {
 public:
  explicit NodeProcess(const std::string& log) {
    // Everything the child needs is made before fork(): this process has threads (the spinner),
    // so the child may only make async-signal-safe calls (no allocation) until exec.
    const std::string name = std::string("__name:=") + (kNodeName + 1);
    pid_ = fork();
    if (pid_ == 0) {
      const int fd = ::open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
      if (fd >= 0) {
        dup2(fd, STDOUT_FILENO);
        dup2(fd, STDERR_FILENO);
      }
      execl(TORO_NODE_BIN, TORO_NODE_BIN, name.c_str(), static_cast<char*>(nullptr));
      _exit(127);
    }
  }
  ~NodeProcess() {
    if (pid_ > 0 && !reaped_) {
      ::kill(pid_, SIGKILL);
      waitpid(pid_, nullptr, 0);
    }
  }
  // SIGKILL and reap; true if it died of it.
  bool kill9() {
    ::kill(pid_, SIGKILL);
    int st = 0;
    waitpid(pid_, &st, 0);
    reaped_ = true;
    return WIFSIGNALED(st) && WTERMSIG(st) == SIGKILL;
  }
  // SIGTERM (what systemd or docker stop send) and reap; true if it exited with status 0.
  bool terminate() {
    ::kill(pid_, SIGTERM);
    int st = 0;
    waitpid(pid_, &st, 0);
    reaped_ = true;
    return WIFEXITED(st) && WEXITSTATUS(st) == 0;
  }
  bool started() const { return pid_ > 0; }

 private:
  pid_t pid_ = -1;
  bool reaped_ = false;
};

struct BagMessage {
  ros::Time time;
  nav_msgs::Odometry::ConstPtr odometry;
  LoopClosure::ConstPtr loop_closure;
};

std::vector<BagMessage> readSample(const std::string& bag_path) {
  rosbag::Bag bag(bag_path, rosbag::bagmode::Read);
  const std::string odom = resolveName("/", names::kOdometryTopic), lc = resolveName("/", names::kLoopClosureTopic);
  std::vector<BagMessage> out;
  for (const rosbag::MessageInstance& m : rosbag::View(bag, rosbag::TopicQuery({odom, lc})))
    out.push_back(BagMessage{m.getTime(), m.getTopic() == odom ? m.instantiate<nav_msgs::Odometry>() : nullptr,
                             m.getTopic() == lc ? m.instantiate<LoopClosure>() : nullptr});
  return out;
}

class Player {
 public:
  Player() {
    ros::NodeHandle nh;
    clock_ = nh.advertise<rosgraph_msgs::Clock>("/clock", 100);
    odom_ = nh.advertise<nav_msgs::Odometry>(resolveName("/", names::kOdometryTopic), 10000);
    lc_ = nh.advertise<LoopClosure>(resolveName("/", names::kLoopClosureTopic), 10000);
  }
  bool connected() const { return odom_.getNumSubscribers() > 0 && lc_.getNumSubscribers() > 0; }
  // Publishes [from, to) in chunks, each time waiting until the node has taken in all odometry so
  // far (its subscriber queues hold 100 messages: a chunk never overflows them) and its background
  // finish, if one runs, has been merged: the uninterrupted run it is compared with (toro_offline)
  // runs each finish inline where it is due.  With chunks of 40 the live node's finishes merged at
  // messages that depended on timing, and the shared keyframes ended 0.63 m apart instead of
  // 0.13-0.14 m in 2 of 3 fresh-clone CI runs of session 31 (3 of the 9 runs of this test in them;
  // never in isolated runs); one message per chunk makes the live run follow the offline one
  // (0.1435 m in every run since).
  bool play(const std::vector<BagMessage>& msgs, std::size_t from, std::size_t to, std::uint64_t odometry_before) {
    std::uint64_t odometry = odometry_before;
    for (std::size_t i = from; i < to; ++i) {
      rosgraph_msgs::Clock c;
      c.clock = msgs[i].time;
      clock_.publish(c);
      if (msgs[i].odometry) {
        odom_.publish(msgs[i].odometry);
        ++odometry;
      } else {
        lc_.publish(msgs[i].loop_closure);
      }
      if ((i + 1 - from) % kChunk == 0 || i + 1 == to) {
        const bool caught_up = waitWall(
            [&] {
              const auto s = status();
              return s && s->odometry_messages == odometry && s->queue_length == 0 && !s->finish_running;
            },
            30.0);
        if (!caught_up) return false;
      }
    }
    return true;
  }

 private:
  ros::Publisher clock_, odom_, lc_;
};

void setNodeParameters(const std::string& autosave) {
  const XmlRpc::XmlRpcValue config = readFlatYaml(std::string(TORO_SOURCE_DIR) + "/config/replay_sample.yaml");
  XmlRpc::XmlRpcValue c = config;
  for (auto it = c.begin(); it != c.end(); ++it) ros::param::set(std::string(kNodeName) + "/" + it->first, it->second);
  ros::param::set(std::string(kNodeName) + "/autosave_path", autosave);
  ros::param::set(std::string(kNodeName) + "/load_path", autosave);
  ros::param::set(std::string(kNodeName) + "/autosave_period_sec", kAutosavePeriodSec);
  ros::param::set(std::string(kNodeName) + "/resume_link", std::string("continue"));
  // ~save_graph below saves by name into the same directory.
  ros::param::set(std::string(kNodeName) + "/graph_directory", fs::path(autosave).parent_path().string());
}

std::string readFile(const std::string& path) {
  std::ifstream in(path);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

TEST(KillResume, KilledNodeResumesFromItsAutosaveAndLosesAtMostOnePeriod) {
  const fs::path dir = fs::temp_directory_path() / ("toro_kill_resume_" + std::to_string(getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::string autosave = (dir / "autosave.g2o").string(), log = (dir / "node.log").string();
  const std::string bag = sampleDir() + "/sample.bag";
  const std::vector<BagMessage> msgs = readSample(bag);
  ASSERT_GT(msgs.size(), 500u);
  setNodeParameters(autosave);
  Player player;

  // First run: from the start to the kill.
  const std::size_t kill_at = static_cast<std::size_t>(kKillFraction * msgs.size());
  {
    NodeProcess first(log);
    ASSERT_TRUE(first.started());
    ASSERT_TRUE(waitWall([&] { return player.connected() && status().has_value(); }, 30.0)) << readFile(log);
    ASSERT_TRUE(player.play(msgs, 0, kill_at, 0)) << readFile(log);
    ASSERT_TRUE(first.kill9());
  }
  ASSERT_TRUE(fs::exists(autosave)) << "no autosave before the kill\n" << readFile(log);
  const Sidecar saved = readSidecar(sidecarPath(autosave));
  ASSERT_FALSE(saved.keyframes.empty());
  const ros::Time saved_newest = saved.keyframes.back().stamp, killed_at = msgs[kill_at - 1].time;
  std::cout << "killed at " << killed_at << " s; the autosave on disk ends at " << saved_newest << " s ("
            << saved.keyframes.size() << " keyframes)\n";
  // The autosave is at most one period (+ one odometry period) older than the last message.
  EXPECT_LE((killed_at - saved_newest).toSec(), kAutosavePeriodSec + 0.1);

  // Second run: resumes the autosave, then the replay goes on after the kill.
  NodeProcess second(log);
  ASSERT_TRUE(waitWall([&] { return player.connected() && status().has_value(); }, 30.0)) << readFile(log);
  const GetStatus::Response resumed = *status();
  EXPECT_EQ(resumed.keyframes, saved.keyframes.size());
  ASSERT_TRUE(player.play(msgs, kill_at, msgs.size(), 0)) << readFile(log);
  Optimize opt;
  opt.request.iterations = 20;
  opt.request.mode = "full";
  ASSERT_TRUE(call(names::kOptimizeService, opt) && opt.response.success) << opt.response.message;
  GraphFile save;
  save.request.path = "resumed.g2o";  // relative to graph_directory = dir
  const std::string resumed_path = (dir / "resumed.g2o").string();
  ASSERT_TRUE(call(names::kSaveGraphService, save) && save.response.success) << save.response.message;
  const GetStatus::Response end = *status();
  EXPECT_EQ(end.time_jump_resets, 0u);
  EXPECT_EQ(end.queue_dropped, 0u);
  EXPECT_GT(end.autosaves, 0u);
  // A clean stop saves what the node has: the autosave then holds the whole final graph.
  ASSERT_TRUE(second.terminate()) << readFile(log);
  EXPECT_EQ(readSidecar(sidecarPath(autosave)).keyframes.size(), end.keyframes);
  EXPECT_EQ(toro::readGraph(autosave).numConstraints(), end.constraints);

  // The uninterrupted run: toro_offline on the same bag and configuration, 20 final passes.
  const std::string cmd = std::string(TORO_OFFLINE_BIN) + " " + bag + " --config " + TORO_SOURCE_DIR +
                          "/config/replay_sample.yaml --final-iterations 20 --quiet --no-curve --output-dir " +
                          (dir / "whole").string() + " > /dev/null";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  const toro::PoseGraph whole = toro::readGraph((dir / "whole" / "corrected.g2o").string());
  const Sidecar whole_side = readSidecar(sidecarPath((dir / "whole" / "corrected.g2o").string()));
  const toro::PoseGraph again = toro::readGraph(resumed_path);
  const Sidecar again_side = readSidecar(sidecarPath(resumed_path));

  // Missing keyframes: only those after the autosave and up to the kill.
  std::map<ros::Time, std::size_t> again_index;
  for (std::size_t i = 0; i < again_side.keyframes.size(); ++i) again_index[again_side.keyframes[i].stamp] = i;
  std::size_t missing = 0;
  double max_difference = 0;
  for (std::size_t i = 0; i < whole_side.keyframes.size(); ++i) {
    const ros::Time t = whole_side.keyframes[i].stamp;
    const auto it = again_index.find(t);
    if (it == again_index.end()) {
      ++missing;
      EXPECT_GT(t, saved_newest) << "keyframe " << i << " lost although it was saved";
      EXPECT_LE(t, killed_at + ros::Duration(0.5)) << "keyframe " << i << " lost after the restart";
      continue;
    }
    max_difference = std::max(
        max_difference, (again.node(it->second).pose.translation() - whole.node(i).pose.translation()).norm());
  }
  EXPECT_EQ(again_side.keyframes.size() + missing, whole_side.keyframes.size());
  const TruthTrajectory truth = TruthTrajectory::load(sampleDir() + "/sample.truth.g2o");
  std::vector<toro::Pose3> whole_poses, again_poses;
  for (const toro::Node& n : whole.nodes()) whole_poses.push_back(n.pose);
  for (const toro::Node& n : again.nodes()) again_poses.push_back(n.pose);
  const Score whole_score = scoreKeyframes(whole_side.keyframes, whole_poses, truth);
  const Score again_score = scoreKeyframes(again_side.keyframes, again_poses, truth);
  std::cout << "missing keyframes " << missing << " of " << whole_side.keyframes.size()
            << "; largest position difference on the others " << max_difference << " m\n"
            << "uninterrupted: " << describeScore(whole_score) << "\nkilled+resumed: " << describeScore(again_score)
            << "\n";
  RecordProperty("missing_keyframes", std::to_string(missing));
  RecordProperty("max_position_difference_m", std::to_string(max_difference));
  // Tolerances: the resumed graph lacks the stretch between autosave and kill, so it is not the
  // same graph; it must be as good a map (RMSE within 25 % + 5 cm) and place the shared keyframes
  // within 0.25 m (the sample's odometry drifts by metres: RMSE ~1.1 m uncorrected).
  EXPECT_LT(again_score.corrected.rmse_m, 1.25 * whole_score.corrected.rmse_m + 0.05);
  EXPECT_LT(max_difference, 0.25);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace offline
}  // namespace toro_ros

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "kill_resume_test");
  ros::AsyncSpinner spinner(1);
  spinner.start();
  return RUN_ALL_TESTS();
}
