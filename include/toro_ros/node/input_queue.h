// The bounded input queue between the ROS callbacks and the worker thread: a mutex and a condition
// variable (the worker sleeps until something arrives or it is stopped; it polls only while a
// background finish waits for its time, see PipelineWorker::loop).
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <mutex>

namespace toro_ros {

template <class T>
class InputQueue {
 public:
  explicit InputQueue(std::size_t capacity) : capacity_(capacity) {}

  // Appends unless the queue holds `capacity` items (then the item is dropped and counted: a
  // callback must never block).  Returns false when dropped.
  bool push(T item) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (items_.size() >= capacity_) {
        ++dropped_;
        return false;
      }
      items_.push_back(std::move(item));
    }
    cv_.notify_one();
    return true;
  }

  // Appends regardless of the bound (service commands: few, and each one has a waiting caller).
  void pushAlways(T item) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      items_.push_back(std::move(item));
    }
    cv_.notify_one();
  }

  // Moves every queued item into `out`.  With `wait`, first sleeps until there is one or stop()
  // was called.  Returns false once stopped.
  bool popAll(std::deque<T>& out, bool wait) {
    std::unique_lock<std::mutex> lock(mutex_);
    if (wait) cv_.wait(lock, [&] { return stopped_ || !items_.empty(); });
    return takeAll(lock, out);
  }
  // As popAll waiting, but for at most `timeout` (then `out` may stay empty).
  bool popAllFor(std::deque<T>& out, std::chrono::duration<double> timeout) {
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait_for(lock, timeout, [&] { return stopped_ || !items_.empty(); });
    return takeAll(lock, out);
  }

  void stop() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stopped_ = true;
    }
    cv_.notify_all();
  }

  std::size_t size() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return items_.size();
  }
  std::uint64_t dropped() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return dropped_;
  }

 private:
  // Under the lock: moves every item into `out`; false once stopped.
  bool takeAll(std::unique_lock<std::mutex>&, std::deque<T>& out) {
    if (stopped_) return false;
    for (T& item : items_) out.push_back(std::move(item));
    items_.clear();
    return true;
  }

  const std::size_t capacity_;
  mutable std::mutex mutex_;  // guards items_, stopped_, dropped_
  std::condition_variable cv_;
  std::deque<T> items_;
  bool stopped_ = false;
  std::uint64_t dropped_ = 0;
};

}  // namespace toro_ros
