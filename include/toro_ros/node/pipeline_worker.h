// The thread that owns a Pipeline: messages in through a bounded queue (never blocking the
// caller), commands in through the same queue with a future for their answer, results out as
// immutable Snapshots.  The pipeline's background finish runs in a second thread on its own copy
// of the graph; its outcome comes back through the queue as a command (the merge), so the
// pipeline is only ever touched by the worker thread and input never waits for a finish.  No ROS transport here (no NodeHandle, no spinning), so the threading is
// tested by a plain gtest under ThreadSanitizer (test/node/test_pipeline_worker.cpp);
// MapCorrectorNode only wires subscriptions, services and timers to it.
#pragma once

#include <atomic>
#include <chrono>
#include <deque>
#include <functional>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <variant>

#include "toro_ros/node/input_queue.h"
#include "toro_ros/pipeline/input_table.h"
#include "toro_ros/pipeline/pipeline.h"

namespace toro_ros {

class PipelineWorker {
 public:
  using Command = std::function<void(Pipeline&)>;
  using ErrorSink = std::function<void(const std::string&)>;
  // Sees every snapshot the moment it is made, with the pipeline it was made from (read only), on
  // the thread that made it: for outputs that need more than a Snapshot holds (the ~graph
  // message: measurements and covariances), built consistently with it and without a copy of
  // the graph.  It must not block; what it does delays the worker.
  using SnapshotObserver = std::function<void(const Pipeline&, const Snapshot&)>;

  // Takes the pipeline (nobody else may touch it until stop()) and starts the thread.  `on_error`
  // gets the text of an exception a message or command threw (a bug: the worker goes on).
  // `observer` (optional) is called for the first snapshot here, then on the worker thread.
  PipelineWorker(std::unique_ptr<Pipeline> pipeline, std::size_t queue_capacity, ErrorSink on_error,
                 SnapshotObserver observer = nullptr);
  ~PipelineWorker();  // stop()

  PipelineWorker(const PipelineWorker&) = delete;
  PipelineWorker& operator=(const PipelineWorker&) = delete;

  // Queues a message unless the queue is full (then it is dropped and counted; false).
  bool push(PipelineMessage message) { return queue_.push(Item(std::move(message))); }

  // Runs `f` on the worker between optimisation passes and waits up to `timeout` for its result:
  // nullopt on timeout (the command still runs later) or if `f` threw (reported to on_error).
  // Commands are never dropped by the queue bound: each has a caller waiting for it.
  template <class R>
  std::optional<R> call(std::function<R(Pipeline&)> f, std::chrono::duration<double> timeout);
  // Runs `f` on the worker between passes without waiting for it (never dropped); a snapshot is
  // published after it, as after every command.
  void post(Command f) {
    queue_.pushAlways(Item(Command([this, f = std::move(f)](Pipeline& pipeline) {
      f(pipeline);
      publishSnapshot();
    })));
  }

  // The newest published state; never blocks on the worker.
  std::shared_ptr<const Snapshot> snapshot() const;
  std::size_t queueLength() const { return queue_.size(); }
  std::uint64_t dropped() const { return queue_.dropped(); }

  // Stops the thread (input still queued is not applied: a shutdown should not wait for a
  // backlog; a running finish is cancelled at its next iteration) and joins it.  Idempotent.  Afterwards pipeline() may be used by the caller's thread.
  void stop();
  Pipeline& pipeline();  // only after stop()

  // Batches in a row after which a due finish starts even though input is waiting (before, the
  // input goes first: startFinishIfDue).
  static constexpr int kMaxFinishDeferrals = 8;

 private:
  using Item = std::variant<PipelineMessage, Command>;
  void loop();
  void process(Item& item);
  void publishSnapshot();
  // Hands a due finish job to the finish thread (when none is running).
  void startFinishIfDue();

  std::unique_ptr<Pipeline> pipeline_;  // touched only by the worker thread until stop()
  ErrorSink on_error_;
  SnapshotObserver observer_;
  InputQueue<Item> queue_;
  std::atomic<bool> stopped_{false};
  mutable std::mutex snapshot_mutex_;  // guards snapshot_ (the pointer, not the pointee)
  std::shared_ptr<const Snapshot> snapshot_;
  std::thread thread_;
  // The finish thread: at most one at a time, started by the worker thread (only it touches
  // finish_thread_), cancelled by stop().
  std::thread finish_thread_;
  std::atomic<bool> finish_running_{false};
  std::atomic<bool> cancel_finish_{false};
  int finish_deferrals_ = 0;  // batches a due finish has waited for queued input (worker thread only)
  // When the newest odometry message was fed (worker thread only): the pipeline's schedule clock
  // runs on from it while odometry is quiet (Pipeline::setOdometryQuietSec).
  std::optional<std::chrono::steady_clock::time_point> last_odometry_fed_;
  static constexpr std::chrono::milliseconds kFinishRecheck{100};
};

template <class R>
std::optional<R> PipelineWorker::call(std::function<R(Pipeline&)> f, std::chrono::duration<double> timeout) {
  auto promise = std::make_shared<std::promise<R>>();
  std::future<R> result = promise->get_future();
  queue_.pushAlways(Item(Command([this, promise, f = std::move(f)](Pipeline& pipeline) {
    // The snapshot is published before the answer: a caller that reads it after the answer sees
    // what the command did (and every message queued before it).
    try {
      R answer = f(pipeline);
      publishSnapshot();
      promise->set_value(std::move(answer));
    } catch (...) {
      publishSnapshot();
      promise->set_exception(std::current_exception());
    }
  })));
  if (result.wait_for(timeout) != std::future_status::ready) return std::nullopt;
  try {
    return result.get();
  } catch (const std::exception& e) {
    if (on_error_) on_error_(std::string("command failed: ") + e.what());
    return std::nullopt;
  }
}

}  // namespace toro_ros
