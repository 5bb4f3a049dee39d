// PipelineWorker: the node's worker thread without ROS transport.  These are the worker-thread
// tests scripts/sanitize.sh runs under ThreadSanitizer: producers, service-like commands and
// snapshot readers on other threads while the worker applies messages and optimises.
#include <atomic>
#include <chrono>
#include <cstdio>
#include <functional>
#include <future>
#include <stdexcept>
#include <thread>
#include <vector>

#include <boost/make_shared.hpp>
#include <gtest/gtest.h>

#include "../pipeline/drift_scenario.h"
#include "toro_ros/core/metrics.h"
#include "toro_ros/core/sparse_finisher.h"
#include "toro_ros/node/pipeline_worker.h"

using namespace toro_ros;
using toro_ros::testing::DriftScenario;
using toro_ros::testing::makeDriftingSquare;
using toro_ros::testing::trueLoopClosure;

namespace {

using std::chrono::duration;
constexpr duration<double> kAnswer{30.0};  // generous: only a hung worker should ever hit it

PipelineOptions options() {
  PipelineOptions o = toro_ros::testing::baseTestOptions();
  o.optimization.full_every_keyframes = 10;
  o.optimization.full_iterations = 5;
  return o;
}

PipelineMessage message(const nav_msgs::Odometry& m) { return boost::make_shared<nav_msgs::Odometry>(m); }
PipelineMessage message(const LoopClosure& m) { return boost::make_shared<LoopClosure>(m); }

struct Errors {
  std::mutex mutex;
  std::vector<std::string> texts;
  PipelineWorker::ErrorSink sink() {
    return [this](const std::string& e) {
      std::lock_guard<std::mutex> lock(mutex);
      texts.push_back(e);
    };
  }
};

// Blocks the worker inside a command until release() (to fill its queue deterministically).
class Gate {
 public:
  explicit Gate(PipelineWorker& w) {
    std::shared_future<void> r = released_.get_future().share();
    std::promise<void>* e = &entered_;
    caller_ = std::thread([&w, r, e] {
      w.call<bool>([r, e](Pipeline&) { return e->set_value(), r.wait(), true; }, kAnswer);
    });
    entered_.get_future().wait();
  }
  ~Gate() { release(); }
  void release() {
    if (!caller_.joinable()) return;
    released_.set_value();
    caller_.join();
  }

 private:
  std::promise<void> entered_, released_;
  std::thread caller_;
};

PipelineStatus status(PipelineWorker& w) {
  const std::optional<PipelineStatus> s = w.call<PipelineStatus>([](Pipeline& p) { return p.status(); }, kAnswer);
  EXPECT_TRUE(s.has_value());
  return s.value_or(PipelineStatus{});
}

// Background finish on, no full rounds (what moves the map is the pass and the finish).
PipelineOptions finishOptions(double min_interval_sec) {
  PipelineOptions o = toro_ros::testing::baseTestOptions();
  o.optimization.full_iterations = 0;
  o.optimization.background_finish = true;
  o.optimization.finish_min_interval_sec = min_interval_sec;
  return o;
}

// A worker on finishOptions, and the errors it reports.
struct FinishWorker {
  explicit FinishWorker(double min_interval_sec)
      : worker(std::make_unique<Pipeline>(finishOptions(min_interval_sec)), 100000, errors.sink()) {}
  Errors errors;  // before the worker, which keeps its sink
  PipelineWorker worker;
};

// Every odometry message of `sc`, then a loop closure from its start to sample `to`.
void pushRunAndLoopClosure(PipelineWorker& worker, const DriftScenario& sc, std::size_t to) {
  for (const nav_msgs::Odometry& m : sc.odometry) worker.push(message(m));
  worker.push(message(trueLoopClosure(sc, 0, to)));
}

// Polls the status until `merged` finishes were merged and none runs, or `seconds` passed.
PipelineStatus waitForFinishes(PipelineWorker& worker, std::uint64_t merged, double seconds) {
  PipelineStatus s;
  const auto end = std::chrono::steady_clock::now() + duration<double>(seconds);
  while (std::chrono::steady_clock::now() < end) {
    s = status(worker);
    if (s.counters.finishes_merged >= merged && !s.finish_running) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return s;
}

// The g2o chi2 of the plain finish's optimum of `graph`.
double optimumChi2(toro::PoseGraph graph) {
  toro::FinishOptions fo;
  if (!toro::cholmodAvailable()) fo.linear_solver = toro::LinearSolverType::kSimplicialLDLT;
  toro::LevenbergMarquardt(fo).optimize(graph);
  return toro::g2oChi2(graph);
}

}  // namespace

TEST(PipelineWorker, ConcurrentProducersCommandsAndReadersLoseNothing) {
  const DriftScenario sc = makeDriftingSquare();
  Errors errors;
  PipelineWorker worker(std::make_unique<Pipeline>(options()), 100000, errors.sink());
  std::atomic<bool> done{false};
  // Readers as the tf / visualisation timers and the status service: they never block the worker.
  // Snapshots are whole and in order: generations and keyframe counts never go back.
  std::thread reader([&] {
    std::uint64_t generation = 0;
    std::size_t keyframes = 0;
    while (!done) {
      const std::shared_ptr<const Snapshot> s = worker.snapshot();
      EXPECT_GE(s->generation, generation);
      EXPECT_GE(s->keyframes.size(), keyframes);
      if (!s->keyframes.empty()) {
        EXPECT_GE(s->edges.size() + 1, s->keyframes.size());  // one chain
      }
      generation = s->generation;
      keyframes = s->keyframes.size();
    }
  });
  std::thread service([&] {
    while (!done) EXPECT_LE(status(worker).counters.odometry_messages, sc.odometry.size());
  });
  const std::size_t last = sc.odometry.size() - 1;
  std::thread odometry([&] {
    for (const auto& m : sc.odometry) EXPECT_TRUE(worker.push(message(m)));
  });
  odometry.join();
  EXPECT_TRUE(worker.push(message(trueLoopClosure(sc, 0, last))));
  // A command is queued behind every message pushed before it: its answer sees them all.
  const PipelineStatus s = status(worker);
  done = true;
  reader.join();
  service.join();
  EXPECT_EQ(s.counters.odometry_messages, sc.odometry.size());
  EXPECT_EQ(s.counters.odometry_refused, 0u);
  EXPECT_EQ(s.counters.loop_closures_applied, 1u);
  EXPECT_EQ(worker.dropped(), 0u);
  EXPECT_TRUE(errors.texts.empty());
  // The snapshot follows: after the command the newest state is published.
  EXPECT_EQ(worker.snapshot()->keyframes.size(), s.keyframes);
}

TEST(PipelineWorker, CommandsAreAnsweredBetweenPassesOfARunningRound) {
  const DriftScenario sc = makeDriftingSquare();
  PipelineOptions o = options();
  o.optimization.full_every_keyframes = 1;
  o.optimization.full_iterations = 1000000;  // a round that outlasts the test
  o.optimization.background_finish = false;  // a finish would stand in for the round
  Errors errors;
  PipelineWorker worker(std::make_unique<Pipeline>(o), 100000, errors.sink());
  const std::size_t last = sc.odometry.size() - 1;
  for (std::size_t i = 0; i < last; ++i) worker.push(message(sc.odometry[i]));
  worker.push(message(trueLoopClosure(sc, 0, last - 1)));
  worker.push(message(sc.odometry[last]));  // a keyframe after the loop closure: the round is due
  // The round starts after the batch holding the last keyframe; a few calls in, it is running.
  bool in_round = false;
  for (int i = 0; i < 100 && !in_round; ++i)
    in_round = worker.call<bool>([](Pipeline& p) { return p.hasScheduledWork(); }, kAnswer).value_or(false);
  ASSERT_TRUE(in_round);
  // Status, save and pause answered while the round goes on; passes advance between calls.
  const std::uint64_t passes = status(worker).counters.optimization_passes;
  std::uint64_t later = passes;
  for (int i = 0; i < 1000 && later == passes; ++i) later = status(worker).counters.optimization_passes;
  EXPECT_GT(later, passes);
  const auto paused = worker.call<bool>([](Pipeline& p) { return p.setPaused(true), p.paused(); }, kAnswer);
  EXPECT_TRUE(paused.value_or(false));
  const std::uint64_t at_pause = status(worker).counters.optimization_passes;
  EXPECT_EQ(status(worker).counters.optimization_passes, at_pause);  // paused: no pass in between
  // stop() mid-round returns (does not wait for a million passes).
  EXPECT_TRUE(worker.call<bool>([](Pipeline& p) { return p.setPaused(false), true; }, kAnswer).has_value());
  worker.stop();
  EXPECT_TRUE(worker.pipeline().hasScheduledWork());
  EXPECT_TRUE(errors.texts.empty());
}

TEST(PipelineWorker, FullQueueDropsAndCountsCommandsAreNeverDropped) {
  const DriftScenario sc = makeDriftingSquare(1);
  PipelineWorker worker(std::make_unique<Pipeline>(options()), 10, nullptr);
  Gate gate(worker);  // the worker is inside a command: nothing is taken off the queue
  std::size_t accepted = 0;
  for (std::size_t i = 0; i < 25; ++i) accepted += worker.push(message(sc.odometry[i]));
  EXPECT_EQ(accepted, 10u);
  EXPECT_EQ(worker.dropped(), 15u);
  EXPECT_EQ(worker.queueLength(), 10u);
  // A command beyond the bound still gets in (its caller is waiting for it).
  std::future<std::optional<PipelineStatus>> answer = std::async(std::launch::async, [&] {
    return worker.call<PipelineStatus>([](Pipeline& p) { return p.status(); }, kAnswer);
  });
  gate.release();
  const std::optional<PipelineStatus> s = answer.get();
  ASSERT_TRUE(s.has_value());
  EXPECT_EQ(s->counters.odometry_messages, 10u);
}

TEST(PipelineWorker, TimeoutAndThrowingCommandsLeaveTheWorkerRunning) {
  Errors errors;
  PipelineWorker worker(std::make_unique<Pipeline>(options()), 100, errors.sink());
  Gate gate(worker);
  // Times out while the worker is busy; the command owns its data and still runs afterwards.
  const std::string why = "set by a command that timed out";
  const auto late = worker.call<bool>([why](Pipeline& p) { return p.reset(why), true; }, duration<double>(0.01));
  EXPECT_FALSE(late.has_value());
  gate.release();
  EXPECT_EQ(status(worker).counters.resets, 1u);  // the late command ran before this one

  const auto thrown = worker.call<int>([](Pipeline&) -> int { throw std::runtime_error("boom"); }, kAnswer);
  EXPECT_FALSE(thrown.has_value());
  ASSERT_EQ(errors.texts.size(), 1u);
  EXPECT_NE(errors.texts[0].find("boom"), std::string::npos);
  EXPECT_EQ(status(worker).counters.resets, 1u);  // still answering
}

// A huge burst: 60 s of 1 kHz odometry and 50 Hz loop closures pushed as fast as a thread can,
// into the node's default queue bound.  Every message is either taken by the pipeline (applied or
// refused with a reason) or dropped at the queue and counted; the queue never exceeds its bound.
TEST(PipelineWorker, BurstBeyondTheQueueIsAccountedFor) {
  constexpr std::size_t kCapacity = 2000;
  PipelineOptions o = options();
  o.keyframer.distance_m = 0.25;
  PipelineWorker worker(std::make_unique<Pipeline>(o), kCapacity, nullptr);
  std::size_t sent = 0, max_queue = 0;
  toro::Pose3 pose;
  const toro::Pose3 step = toro::Pose3::fromRollPitchYaw(0.001, 0, 0, 0, 0, 0.0001);
  for (int i = 1; i <= 60000; ++i) {
    pose = pose * step;
    const ros::Time t(100.0 + 0.001 * i);
    worker.push(message(toro_ros::testing::odometryMsg(t, pose)));
    ++sent;
    if (i % 20 == 0 && i > 2000) {
      LoopClosure lc;
      lc.header.stamp = t;
      lc.stamp_from = ros::Time(100.0 + 0.001 * (i - 2000));
      lc.stamp_to = t;
      lc.id_from = lc.id_to = -1;
      lc.from_T_to.orientation.w = 1.0;
      worker.push(message(lc));
      ++sent;
    }
    max_queue = std::max(max_queue, worker.queueLength());
  }
  const PipelineStatus s = status(worker);
  const PipelineCounters& c = s.counters;
  std::printf("burst: %zu sent, %lu dropped at the queue, %lu odometry and %lu loop closures taken, max queue %zu\n",
              sent, static_cast<unsigned long>(worker.dropped()), static_cast<unsigned long>(c.odometry_messages),
              static_cast<unsigned long>(c.loop_closures_received), max_queue);
  EXPECT_EQ(c.odometry_messages + c.loop_closures_received + worker.dropped(), sent);
  // Messages never exceed the bound; commands are never dropped, and the background finish's merge
  // is one (at most one is out at a time).
  EXPECT_LE(max_queue, kCapacity + 1);
  EXPECT_GT(worker.dropped(), 0u);  // the burst did outrun the worker
  // What was taken is accounted for by the pipeline too.
  EXPECT_EQ(c.loop_closures_applied + c.loop_closures_refused + s.pending_loop_closures, c.loop_closures_received);
}

TEST(PipelineWorker, PipelineIsOnlyHandedOutAfterStop) {
  PipelineWorker worker(std::make_unique<Pipeline>(options()), 10, nullptr);
  EXPECT_THROW(worker.pipeline(), std::logic_error);
  worker.stop();
  worker.stop();  // idempotent
  EXPECT_TRUE(worker.pipeline().graph().empty());
  EXPECT_THROW(PipelineWorker(nullptr, 10, nullptr), std::invalid_argument);
}

// The snapshot observer sees every snapshot on the worker thread together with the pipeline it
// was made from, nothing in between (what ~graph relies on); post() runs a command without waiting.
TEST(PipelineWorker, ObserverSeesEachSnapshotWithTheStateItWasMadeFrom) {
  const DriftScenario s = makeDriftingSquare();
  std::atomic<int> calls{0}, mismatches{0};
  std::atomic<std::uint64_t> last_generation{0};
  std::atomic<bool> out_of_order{false};
  Errors errors;
  PipelineWorker worker(std::make_unique<Pipeline>(options()), 100000, errors.sink(),
                        [&](const Pipeline& p, const Snapshot& snap) {
                          ++calls;
                          if (snap.keyframes.size() != p.keyframes().size() ||
                              snap.edges.size() != p.graph().numConstraints())
                            ++mismatches;
                          if (snap.generation <= last_generation) out_of_order = true;
                          last_generation = snap.generation;
                        });
  EXPECT_EQ(calls, 1);  // the first snapshot, made in the constructor
  for (const auto& m : s.odometry) worker.push(message(m));
  worker.push(message(trueLoopClosure(s, 0, s.odometry.size() - 1)));
  std::promise<std::size_t> posted;
  worker.post([&posted](Pipeline& p) { posted.set_value(p.keyframes().size()); });
  std::future<std::size_t> keyframes = posted.get_future();
  ASSERT_EQ(keyframes.wait_for(kAnswer), std::future_status::ready);
  EXPECT_GT(keyframes.get(), 20u);
  ASSERT_TRUE(worker.call<bool>([](Pipeline&) { return true; }, kAnswer).has_value());
  worker.stop();
  EXPECT_GT(calls, 2);
  EXPECT_EQ(mismatches, 0);
  EXPECT_FALSE(out_of_order);
  EXPECT_EQ(worker.snapshot()->generation, last_generation);
  EXPECT_TRUE(errors.texts.empty());
}

// The background finish runs beside the worker: the worker keeps answering while it runs, and its
// merge is published like any other change, bringing the snapshot to the optimum.
TEST(PipelineWorker, BackgroundFinishIsMergedAndPublished) {
  const DriftScenario sc = makeDriftingSquare();
  FinishWorker run(0.0);
  PipelineWorker& worker = run.worker;
  pushRunAndLoopClosure(worker, sc, sc.odometry.size() - 1);
  const PipelineStatus s = waitForFinishes(worker, 1, 10.0);
  ASSERT_EQ(s.counters.finishes_merged, 1u);
  EXPECT_EQ(s.counters.finishes_started, 1u);
  EXPECT_FALSE(s.finish_running);
  const std::shared_ptr<const Snapshot> snapshot = worker.snapshot();
  ASSERT_TRUE(snapshot->last_finish);
  EXPECT_TRUE(snapshot->last_finish->merged);
  worker.stop();
  // The published chi2 is the optimum's.
  const double best = optimumChi2(worker.pipeline().graph());
  EXPECT_NEAR(snapshot->chi2, best, 1e-4 * best);
  EXPECT_TRUE(run.errors.texts.empty());
}

// Taking a finish job costs the worker a pass over the whole map, so a due finish waits while input is queued
// (a revisit's releasing loop closure came a few milliseconds after the ones that made the finish due, and
// waited behind the copy), but only kMaxFinishDeferrals batches: here a chain of commands, each queueing the
// next, keeps the queue from ever being empty when a batch ends.
TEST(PipelineWorker, ADueFinishWaitsForQueuedInputButASteadyStreamCannotStarveIt) {
  const DriftScenario sc = makeDriftingSquare();
  FinishWorker run(0.0);
  PipelineWorker& worker = run.worker;
  std::atomic<bool> started{false};
  std::atomic<int> pending_steps{0};  // steps that found a finish due and none started
  std::atomic<int> steps{0};
  std::function<void(Pipeline&)> step = [&](Pipeline& p) {
    if (p.status().counters.finishes_started > 0) {
      started = true;
      return;
    }
    if (p.finishPending()) ++pending_steps;
    if (++steps < 10000) worker.post(step);
  };
  pushRunAndLoopClosure(worker, sc, sc.odometry.size() - 1);
  worker.post(step);
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(20);
  while (!started && std::chrono::steady_clock::now() < end)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  ASSERT_TRUE(started) << "no finish while the queue was never empty (" << steps << " steps)";
  // Deferred for the batches the cap allows (the first step may run in the loop closure's own
  // batch, before the check), then started although input was still queued.
  EXPECT_GE(pending_steps.load(), 2);  // it did wait
  EXPECT_GE(pending_steps.load(), PipelineWorker::kMaxFinishDeferrals);
  EXPECT_LE(pending_steps.load(), PipelineWorker::kMaxFinishDeferrals + 1);
  EXPECT_LT(steps.load(), 10000);
  ASSERT_EQ(waitForFinishes(worker, 1, 10.0).counters.finishes_merged, 1u);
  EXPECT_TRUE(run.errors.texts.empty());
}

// Loop closures that come after the odometry stopped (a bag ended, a recogniser working off its
// queue) still get their finish: the schedule's clock runs on while odometry is quiet.  Before,
// the finish interval was counted in message time only, which had stopped at the last odometry
// stamp, so the second finish never came and the map stayed where TORO's passes left it.
TEST(PipelineWorker, AFinishStillComesForLoopClosuresAfterTheOdometryStopped) {
  const DriftScenario sc = makeDriftingSquare();
  FinishWorker run(1.0);
  PipelineWorker& worker = run.worker;
  const std::size_t last = sc.odometry.size() - 1;
  pushRunAndLoopClosure(worker, sc, last / 2);
  ASSERT_EQ(waitForFinishes(worker, 1, 10.0).counters.finishes_merged, 1u);
  // The end of the first lap is the start again, and so is the end: a second loop closure, no
  // odometry after it.
  worker.push(message(trueLoopClosure(sc, 0, last)));
  const auto sent = std::chrono::steady_clock::now();
  const PipelineStatus s = waitForFinishes(worker, 2, 10.0);
  const double waited = duration<double>(std::chrono::steady_clock::now() - sent).count();
  ASSERT_EQ(s.counters.finishes_merged, 2u)
      << "no second finish " << waited << " s after the loop closure (applied "
      << s.counters.loop_closures_applied << ", held " << s.counters.loop_closures_held << ", started "
      << s.counters.finishes_started << ")";
  EXPECT_EQ(s.counters.loop_closures_applied, 2u);
  // Not before the interval (in the wall time the clock ran on by), not much after it.
  EXPECT_GE(waited, 0.5);  // finish_min_interval_sec 1
  const std::shared_ptr<const Snapshot> snapshot = worker.snapshot();
  worker.stop();
  const double best = optimumChi2(worker.pipeline().graph());
  EXPECT_NEAR(snapshot->chi2, best, 1e-4 * best);
  EXPECT_TRUE(run.errors.texts.empty());
}
