#include "toro_ros/node/pipeline_worker.h"

#include <stdexcept>

namespace toro_ros {

PipelineWorker::PipelineWorker(std::unique_ptr<Pipeline> pipeline, std::size_t queue_capacity,
                               ErrorSink on_error, SnapshotObserver observer)
    : pipeline_(std::move(pipeline)),
      on_error_(std::move(on_error)),
      observer_(std::move(observer)),
      queue_(queue_capacity) {
  if (!pipeline_) throw std::invalid_argument("PipelineWorker needs a pipeline");
  snapshot_ = pipeline_->makeSnapshot();
  if (observer_) observer_(*pipeline_, *snapshot_);
  thread_ = std::thread(&PipelineWorker::loop, this);
}

PipelineWorker::~PipelineWorker() { stop(); }

void PipelineWorker::stop() {
  cancel_finish_ = true;
  queue_.stop();
  if (thread_.joinable()) thread_.join();
  if (finish_thread_.joinable()) finish_thread_.join();
  stopped_ = true;
}

void PipelineWorker::startFinishIfDue() {
  if (finish_running_) return;
  // Input that came in meanwhile goes first: taking a job costs the worker a pass over the whole
  // map (every pose and weight, MapOptimizer::finishGraph; a full copy of the graph once, 24-38 ms
  // at 100,000 keyframes), and a loop closure queued behind it waits that long for its correction.
  // A revisit's loop closures come a few milliseconds apart and the first ones make a finish due,
  // so the one that releases the revisit was nearly always the one kept waiting
  // (bench/node_results.md, session 39).  At most kMaxFinishDeferrals batches in a row: a steady
  // stream of input cannot starve the finish.
  if (!pipeline_->finishPending()) {
    finish_deferrals_ = 0;
    return;
  }
  if (queue_.size() > 0 && finish_deferrals_ < kMaxFinishDeferrals) {
    ++finish_deferrals_;
    return;
  }
  std::optional<FinishJob> job = pipeline_->takeFinishJob();
  if (!job) return;
  finish_deferrals_ = 0;
  if (finish_thread_.joinable()) finish_thread_.join();  // the previous one has posted its merge
  finish_running_ = true;
  finish_thread_ = std::thread([this, job = std::move(*job)]() mutable {
    auto outcome = std::make_shared<const FinishOutcome>(
        runFinishJob(std::move(job), [this] { return cancel_finish_.load(); }));
    // The merge is a command like any other: it runs between passes, on the worker thread, and
    // the snapshot published after it is the first to show the finished map.  A merge queued
    // after stop() is simply never run.
    post([this, outcome](Pipeline& pipeline) {
      finish_running_ = false;
      pipeline.mergeFinish(*outcome);
    });
  });
}

Pipeline& PipelineWorker::pipeline() {
  if (!stopped_) throw std::logic_error("PipelineWorker::pipeline() before stop()");
  return *pipeline_;
}

std::shared_ptr<const Snapshot> PipelineWorker::snapshot() const {
  std::lock_guard<std::mutex> lock(snapshot_mutex_);
  return snapshot_;
}

void PipelineWorker::publishSnapshot() {
  const std::shared_ptr<const Snapshot> s = pipeline_->makeSnapshot();
  {
    // Readers see it before the observer runs: an observer that sends from it (the node's tf on a
    // correction) is never followed by a reader's older snapshot.
    std::lock_guard<std::mutex> lock(snapshot_mutex_);
    snapshot_ = s;
  }
  if (observer_) {
    try {
      observer_(*pipeline_, *s);
    } catch (const std::exception& e) {
      if (on_error_) on_error_(std::string("snapshot observer failed: ") + e.what());
    }
  }
}

void PipelineWorker::process(Item& item) {
  if (auto* command = std::get_if<Command>(&item)) {
    // Commands change the map (reset, load, optimise) or are asked about it: each publishes a
    // snapshot at once (call, post), not at the next message.
    (*command)(*pipeline_);
  } else {
    feedPipeline(*pipeline_, std::get<PipelineMessage>(item));
  }
}

void PipelineWorker::loop() {
  std::deque<Item> batch;
  // Sleep only when no optimisation round is in progress; otherwise take what came in and go on,
  // so messages and commands wait at most one pass.  A finish that is due but waits (for its
  // interval, on a clock that runs on while odometry is quiet) has the worker look again every
  // kFinishRecheck instead of sleeping until the next message, which may never come.
  auto take = [&] {
    if (pipeline_->hasScheduledWork()) return queue_.popAll(batch, false);
    if (!finish_running_ && pipeline_->finishPending()) return queue_.popAllFor(batch, kFinishRecheck);
    return queue_.popAll(batch, true);
  };
  while (take()) {
    const std::uint64_t before = pipeline_->revision();
    for (Item& item : batch) {
      if (const auto* m = std::get_if<PipelineMessage>(&item);
          m && std::holds_alternative<nav_msgs::Odometry::ConstPtr>(*m))
        last_odometry_fed_ = std::chrono::steady_clock::now();
      // The pipeline reports bad input as counted refusals; an exception here is a bug, and the
      // worker keeps running (and says so) rather than taking the robot's map down with it.
      try {
        process(item);
      } catch (const std::exception& e) {
        if (on_error_) on_error_(std::string("input dropped after an internal error: ") + e.what());
      }
    }
    batch.clear();
    if (last_odometry_fed_)
      pipeline_->setOdometryQuietSec(
          std::chrono::duration<double>(std::chrono::steady_clock::now() - *last_odometry_fed_).count());
    pipeline_->runScheduledOptimization();
    if (pipeline_->revision() != before) publishSnapshot();
    startFinishIfDue();
  }
}

}  // namespace toro_ros
