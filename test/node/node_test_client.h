// What the node's rostest clients share: a client that publishes /clock itself (simulated time
// advances 1:1 with wall time unless odometry pushes it ahead), publishes odometry and loop
// closures, calls the node's services and keeps the latest of everything the node publishes.
// `node` is the node's resolved name (its private namespace), e.g. "/map_corrector"; `map_frame`
// the node's map_frame (map -> odom transforms in other frames are ignored).
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <diagnostic_msgs/DiagnosticArray.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <gtest/gtest.h>
#include <nav_msgs/Path.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Clock.h>
#include <rosgraph_msgs/Log.h>
#include <std_srvs/Trigger.h>
#include <tf2_msgs/TFMessage.h>
#include <visualization_msgs/MarkerArray.h>

#include "toro_ros/GetStatus.h"
#include "toro_ros/GraphFile.h"
#include "toro_ros/LoopClosure.h"
#include "toro_ros/Optimize.h"
#include "toro_ros/PoseGraph.h"

namespace toro_ros {
namespace testing {

constexpr double kTimeoutSec = 20.0;

// Latest messages seen by the subscriptions, with a condition variable to wait on.
struct Observed {
  std::mutex mutex;  // guards everything below
  std::condition_variable cv;
  std::optional<geometry_msgs::TransformStamped> map_T_odom;
  // Largest (stamp - our /clock at arrival) of the transforms since tf_count was reset.
  double max_ahead = -1e9;
  int tf_count = 0;
  std::optional<nav_msgs::Path> path;
  std::optional<visualization_msgs::MarkerArray> markers;
  bool saw_delete_all = false;
  std::optional<diagnostic_msgs::DiagnosticStatus> diagnostics;
  std::optional<PoseGraph> graph;
  int graph_count = 0;
  std::optional<geometry_msgs::PoseWithCovarianceStamped> pose;
  int pose_count = 0;
  std::vector<std::string> log;  // /rosout lines of the node
};

class NodeTestClient {
 public:
  explicit NodeTestClient(const std::string& node = "/map_corrector", const std::string& map_frame = "map")
      : node_(node), map_frame_(map_frame) {
    clock_pub_ = nh_.advertise<rosgraph_msgs::Clock>("/clock", 10);
    odom_pub_ = nh_.advertise<nav_msgs::Odometry>("odom", 1000);
    loop_pub_ = nh_.advertise<LoopClosure>("loop_closure", 100);
    tf_sub_ = nh_.subscribe("/tf", 100, &NodeTestClient::onTf, this);
    path_sub_ = nh_.subscribe(node_ + "/path", 10, &NodeTestClient::onPath, this);
    markers_sub_ = nh_.subscribe(node_ + "/graph_markers", 10, &NodeTestClient::onMarkers, this);
    graph_sub_ = nh_.subscribe(node_ + "/graph", 10, &NodeTestClient::onGraph, this);
    pose_sub_ = nh_.subscribe(node_ + "/pose", 1000, &NodeTestClient::onPose, this);
    diagnostics_sub_ = nh_.subscribe("/diagnostics", 10, &NodeTestClient::onDiagnostics, this);
    rosout_sub_ = nh_.subscribe("/rosout", 1000, &NodeTestClient::onLog, this);
    clock_thread_ = std::thread([this] {
      while (!stop_) {
        if (clock_paused_) {
          std::this_thread::sleep_for(std::chrono::milliseconds(5));
          continue;
        }
        const double now = std::max(clock_sec_.load(), last_published_ + 0.005);
        rosgraph_msgs::Clock c;
        c.clock = ros::Time(now);
        clock_pub_.publish(c);
        last_published_ = now;
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
      }
    });
  }
  ~NodeTestClient() {
    stop_ = true;
    clock_thread_.join();
  }

  const std::string& node() const { return node_; }
  void setClock(const ros::Time& t) {
    if (t.toSec() > clock_sec_) clock_sec_ = t.toSec();
  }
  double clock() const { return last_published_; }
  // Stops /clock where it is (as at the end of a bag played with --clock), or lets it run again.
  void pauseClock(bool paused) { clock_paused_ = paused; }

  // Polls `pred` (cheap, or a service call) until true or the timeout.
  static bool waitFor(const std::function<bool()>& pred, double timeout_sec = kTimeoutSec) {
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_sec);
    while (std::chrono::steady_clock::now() < end) {
      if (pred()) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return pred();
  }
  // Waits on the subscriptions' condition variable.
  bool waitObserved(const std::function<bool(const Observed&)>& pred, double timeout_sec = kTimeoutSec) {
    std::unique_lock<std::mutex> lock(observed.mutex);
    return observed.cv.wait_for(lock, std::chrono::duration<double>(timeout_sec),
                                [&] { return pred(observed); });
  }
  template <class T>
  T observedCopy(const std::function<T(const Observed&)>& get) {
    std::lock_guard<std::mutex> lock(observed.mutex);
    return get(observed);
  }

  bool connect() {
    return waitFor([&] {
             return odom_pub_.getNumSubscribers() > 0 && loop_pub_.getNumSubscribers() > 0 &&
                    path_sub_.getNumPublishers() > 0 && markers_sub_.getNumPublishers() > 0 &&
                    graph_sub_.getNumPublishers() > 0 && pose_sub_.getNumPublishers() > 0;
           }) &&
           ros::service::waitForService(node_ + "/get_status", ros::Duration(kTimeoutSec));
  }

  void publishOdometry(const nav_msgs::Odometry& m) {
    setClock(m.header.stamp);
    odom_pub_.publish(m);
    // Pacing, not synchronisation: keeps the burst within the node's subscriber queue.
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  void publishLoopClosure(const LoopClosure& m) { loop_pub_.publish(m); }

  GetStatus::Response status() {
    GetStatus srv;
    EXPECT_TRUE(ros::service::call(node_ + "/get_status", srv));
    return srv.response;
  }
  bool trigger(const std::string& name) {
    std_srvs::Trigger srv;
    return ros::service::call(node_ + "/" + name, srv) && srv.response.success;
  }
  GraphFile::Response graphFile(const std::string& name, const std::string& path) {
    GraphFile srv;
    srv.request.path = path;
    EXPECT_TRUE(ros::service::call(node_ + "/" + name, srv));
    return srv.response;
  }
  Optimize::Response optimize(unsigned iterations, const std::string& mode) {
    Optimize srv;
    srv.request.iterations = iterations;
    srv.request.mode = mode;
    EXPECT_TRUE(ros::service::call(node_ + "/optimize", srv));
    return srv.response;
  }
  // True if a /rosout line of the node contains `text`.
  bool logged(const std::string& text) {
    std::lock_guard<std::mutex> lock(observed.mutex);
    for (const std::string& line : observed.log)
      if (line.find(text) != std::string::npos) return true;
    return false;
  }

  Observed observed;

 private:
  void onTf(const tf2_msgs::TFMessage::ConstPtr& msg) {
    for (const auto& t : msg->transforms) {
      if (t.header.frame_id != map_frame_ || t.child_frame_id != "odom") continue;
      std::lock_guard<std::mutex> lock(observed.mutex);
      observed.map_T_odom = t;
      observed.max_ahead = std::max(observed.max_ahead, t.header.stamp.toSec() - last_published_);
      ++observed.tf_count;
      observed.cv.notify_all();
    }
  }
  void onPath(const nav_msgs::Path::ConstPtr& msg) {
    std::lock_guard<std::mutex> lock(observed.mutex);
    observed.path = *msg;
    observed.cv.notify_all();
  }
  void onDiagnostics(const diagnostic_msgs::DiagnosticArray::ConstPtr& msg) {
    for (const auto& status : msg->status) {
      if (status.name.find("map corrector") == std::string::npos) continue;
      std::lock_guard<std::mutex> lock(observed.mutex);
      observed.diagnostics = status;
      observed.cv.notify_all();
    }
  }
  void onMarkers(const visualization_msgs::MarkerArray::ConstPtr& msg) {
    std::lock_guard<std::mutex> lock(observed.mutex);
    observed.markers = *msg;
    if (!msg->markers.empty() && msg->markers[0].action == visualization_msgs::Marker::DELETEALL)
      observed.saw_delete_all = true;
    observed.cv.notify_all();
  }
  void onGraph(const PoseGraph::ConstPtr& msg) {
    std::lock_guard<std::mutex> lock(observed.mutex);
    observed.graph = *msg;
    ++observed.graph_count;
    observed.cv.notify_all();
  }
  void onPose(const geometry_msgs::PoseWithCovarianceStamped::ConstPtr& msg) {
    std::lock_guard<std::mutex> lock(observed.mutex);
    observed.pose = *msg;
    ++observed.pose_count;
    observed.cv.notify_all();
  }
  void onLog(const rosgraph_msgs::Log::ConstPtr& msg) {
    if (msg->name != node_) return;
    std::lock_guard<std::mutex> lock(observed.mutex);
    observed.log.push_back(msg->msg);
    observed.cv.notify_all();
  }

  std::string node_, map_frame_;
  ros::NodeHandle nh_;
  ros::Publisher clock_pub_, odom_pub_, loop_pub_;
  ros::Subscriber tf_sub_, path_sub_, markers_sub_, graph_sub_, pose_sub_, diagnostics_sub_, rosout_sub_;
  std::atomic<double> clock_sec_{99.0};
  std::atomic<double> last_published_{99.0};
  std::atomic<bool> stop_{false};
  std::atomic<bool> clock_paused_{false};
  std::thread clock_thread_;
};

}  // namespace testing
}  // namespace toro_ros
