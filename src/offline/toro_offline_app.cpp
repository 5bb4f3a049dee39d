#include <unistd.h>

#include <filesystem>
#include <iostream>

#include "toro_ros/offline/apps.h"
#include "toro_ros/offline/cli.h"
#include "toro_ros/offline/graph_to_bag.h"
#include "toro_ros/offline/offline_output.h"

namespace toro_ros {
namespace offline {

namespace {

const std::vector<ArgSpec> kSpecs = {
    {"config", "node parameter file (keys of config/map_corrector.yaml). Default: the node's defaults"},
    {"output-dir", "where corrected.g2o, corrected_poses.bag and summary.json go. Default out/offline"},
    {"namespace",
     "namespace the node would run in; its relative topics odom and loop_closure resolve there. "
     "Default /"},
    {"final-iterations", "full passes after the bag, as ~optimize would run them (0: none). Default 20"},
    {"truth",
     "truth file for scoring (<stem>.truth.g2o from graph_to_bag). Default: <bag stem>.truth.g2o if "
     "it exists"},
    {"start", "start this many seconds into the bag, as rosbag play -s. Default 0"},
    {"duration", "read only this many seconds of the bag, as rosbag play -u (0: to the end). Default 0"},
    {"optimality-every",
     "every this many seconds of message time, compute the optimum of the graph so far on a copy and "
     "record its chi2 beside the published map's in summary.json (a benchmark's measure; 0: never). "
     "Default 0"},
    {"optimality-after-loop-closure",
     "with --optimality-every: take each sample this many seconds of message time after a loop "
     "closure (the first since the last sample) instead of at regular stamps, at most one per "
     "--optimality-every (0: regular stamps). Default 0"},
    {"solver-threads",
     "threads of the finish's linear algebra (OpenBLAS, OpenMP), process-wide; 0 leaves the libraries' "
     "own. Default: the config's finish_threads (1)"},
    {"no-curve", "do not record chi2 after each final pass (saves one extra run of the final passes)", false},
    {"quiet", "no progress bar (there is none either when stderr is not a terminal)", false},
};

OfflineOptions optionsFromArgs(const ParsedArgs& a) {
  OfflineOptions o;
  o.bag_path = a.positional.at(0);
  o.config_path = a.text("config", "");
  o.output_dir = a.text("output-dir", o.output_dir);
  o.topic_namespace = a.text("namespace", o.topic_namespace);
  o.final_iterations = a.integer("final-iterations", o.final_iterations);
  o.iteration_curve = !a.has("no-curve");
  o.start_sec = a.number("start", o.start_sec);
  o.duration_sec = a.number("duration", o.duration_sec);
  o.optimality_every_sec = a.number("optimality-every", o.optimality_every_sec);
  o.optimality_after_loop_closure_sec =
      a.number("optimality-after-loop-closure", o.optimality_after_loop_closure_sec);
  if (a.has("solver-threads")) o.solver_threads = a.integer("solver-threads", 0);
  // A progress bar only for a terminal: in a log file its redraws would be one long line.
  o.progress = !a.has("quiet") && isatty(STDERR_FILENO);
  const std::string beside = bagStem(o.bag_path) + ".truth.g2o";
  o.truth_path = a.text("truth", std::filesystem::exists(beside) ? beside : "");
  return o;
}

}  // namespace

int runToroOffline(int argc, char** argv) {
  const std::string synopsis = "toro_offline BAG [options]";
  try {
    const ParsedArgs args = parseArgs(argc, argv, kSpecs);
    if (args.help || args.positional.size() != 1) {
      std::cerr << usage(synopsis, kSpecs);
      return args.help ? 0 : 2;
    }
    const OfflineOptions options = optionsFromArgs(args);
    OfflineRunner runner(options);
    const OfflineRun run = runner.run();
    // As the node does on shutdown: the config's autosave_path (if any) gets the final graph, so
    // a later run (node or this tool) can resume it with load_path.
    const std::string autosave_error = runner.pipeline().autosave();
    if (!autosave_error.empty()) std::cerr << "toro_offline: autosave: " << autosave_error << "\n";
    const OfflineSummary summary = summarize(runner, run, options);
    writeOutputs(runner, summary, options);
    std::cout << describeSummary(summary) << "wrote " << options.output_dir
              << "/{corrected.g2o, corrected.g2o.stamps, corrected_poses.bag, summary.json}\n";
    return 0;
  } catch (const std::invalid_argument& e) {
    std::cerr << "toro_offline: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "toro_offline: " << e.what() << "\n";
    return 1;
  }
}

}  // namespace offline
}  // namespace toro_ros
