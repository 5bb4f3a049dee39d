#include <iostream>

#include "toro_ros/offline/apps.h"
#include "toro_ros/offline/cli.h"
#include "toro_ros/offline/graph_to_bag.h"

namespace toro_ros {
namespace offline {

namespace {

const std::vector<ArgSpec> kSpecs = {
    {"ground-truth",
     "graph file whose poses are the truth (same ids as the input; without VERTEX lines: the "
     "chain of its noise-free measurements); written as <stem>.truth.g2o"},
    {"reference-iterations",
     "no truth known: optimise the input with this many TORO passes and write the result "
     "as <stem>.reference.g2o (a reference optimum, not a truth). Default 0 (none)"},
    {"rate", "odometry (and tf) messages per second. Default 20"},
    {"speed", "nominal speed between keyframes, m/s. Default 1.0"},
    {"angular-speed", "nominal turn rate, rad/s (a step lasts at least its angle / this). Default 0.5"},
    {"keyframe-period", "every step lasts this long, s (a multiple of 1/rate); 0 = from speed. Default 0"},
    {"start", "stamp of the first message, s. Default 1000"},
    {"latency",
     "loop closures are published this long after the robot reaches their later pose, s. Default 0.02"},
    {"odom-frame", "Default odom"},
    {"base-frame", "Default base_link"},
};

GraphToBagOptions optionsFromArgs(const ParsedArgs& a) {
  GraphToBagOptions o;
  o.input_path = a.positional.at(0);
  o.output_bag = a.positional.at(1);
  o.ground_truth_path = a.text("ground-truth", "");
  o.reference_iterations = a.integer("reference-iterations", o.reference_iterations);
  o.odometry_rate_hz = a.number("rate", o.odometry_rate_hz);
  o.speed_mps = a.number("speed", o.speed_mps);
  o.angular_speed_radps = a.number("angular-speed", o.angular_speed_radps);
  o.keyframe_period_sec = a.number("keyframe-period", o.keyframe_period_sec);
  o.start_sec = a.number("start", o.start_sec);
  o.loop_closure_latency_sec = a.number("latency", o.loop_closure_latency_sec);
  o.odom_frame = a.text("odom-frame", o.odom_frame);
  o.base_frame = a.text("base-frame", o.base_frame);
  return o;
}

}  // namespace

int runGraphToBag(int argc, char** argv) {
  const std::string synopsis = "graph_to_bag INPUT_GRAPH OUTPUT.bag [options]";
  try {
    const ParsedArgs args = parseArgs(argc, argv, kSpecs);
    if (args.help || args.positional.size() != 2) {
      std::cerr << usage(synopsis, kSpecs);
      return args.help ? 0 : 2;
    }
    const GraphToBagResult r = graphToBag(optionsFromArgs(args));
    std::cout << r.keyframes << " keyframes, " << r.odometry_messages << " odometry messages, "
              << r.loop_closures << " loop closures over " << r.duration_sec << " s\n";
    for (const std::string& f : r.written) std::cout << "wrote " << f << "\n";
    return 0;
  } catch (const std::invalid_argument& e) {
    std::cerr << "graph_to_bag: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "graph_to_bag: " << e.what() << "\n";
    return 1;
  }
}

}  // namespace offline
}  // namespace toro_ros
