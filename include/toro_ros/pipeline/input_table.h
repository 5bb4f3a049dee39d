// The pipeline's inputs in one table: topic -> message type -> Pipeline handler.  The live node
// subscribes to these topics and the offline runner reads them from a bag; both feed the messages
// through feedPipeline, so the two cannot drift apart (cartographer_ros's offline node calls the
// same Handle...Message methods as its subscribers).  To add an input, add one row here.
#pragma once

#include <type_traits>
#include <variant>

#include <nav_msgs/Odometry.h>

#include "toro_ros/LoopClosure.h"
#include "toro_ros/node/names.h"
#include "toro_ros/pipeline/pipeline.h"

namespace toro_ros {

// One message of any input type, shared (as the transport and rosbag hand them out).
using PipelineMessage = std::variant<nav_msgs::Odometry::ConstPtr, LoopClosure::ConstPtr>;

// Calls f(topic, handler) for every input, where handler is a pointer to the Pipeline member
// function taking that message type (so the type is deducible from it).
template <class F>
constexpr void forEachPipelineInput(F&& f) {
  f(names::kOdometryTopic, &Pipeline::handleOdometry);
  f(names::kLoopClosureTopic, &Pipeline::handleLoopClosure);
}

// The message type a handler takes: MessageOf<decltype(&Pipeline::handleOdometry)> is Odometry.
template <class Handler>
struct MessageOfHandler;
template <class M>
struct MessageOfHandler<void (Pipeline::*)(const M&)> {
  using type = M;
};
template <class Handler>
using MessageOf = typename MessageOfHandler<Handler>::type;

// True if the table has a row for message type M.
template <class M>
constexpr bool handledByPipeline() {
  bool found = false;
  forEachPipelineInput([&found](const char*, auto handler) {
    if constexpr (std::is_same_v<MessageOf<decltype(handler)>, M>) found = true;
  });
  return found;
}

// Hands one message to the pipeline's handler for its type.
inline void feedPipeline(Pipeline& pipeline, const PipelineMessage& message) {
  std::visit(
      [&pipeline](const auto& msg) {
        using M = std::remove_const_t<typename std::decay_t<decltype(msg)>::element_type>;
        forEachPipelineInput([&](const char*, auto handler) {
          if constexpr (std::is_same_v<MessageOf<decltype(handler)>, M>) (pipeline.*handler)(*msg);
        });
        static_assert(handledByPipeline<M>(), "feedPipeline: a PipelineMessage type has no row in the table");
      },
      message);
}

}  // namespace toro_ros
