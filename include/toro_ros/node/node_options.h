// Options of the map corrector node and the one function that reads them from the private
// parameter namespace (as an XmlRpc dictionary, so it is testable without a master).
#pragma once

#include <set>
#include <string>
#include <vector>

#include <xmlrpcpp/XmlRpcValue.h>

#include "toro_ros/core/sparse_finisher.h"
#include "toro_ros/node/input_health.h"
#include "toro_ros/pipeline/pipeline.h"
#include "toro_ros/pipeline/visualization.h"

namespace toro_ros {

struct NodeOptions {
  std::string map_frame = "map";
  std::string odom_frame = "odom";
  double tf_rate_hz = 50.0;              // map->odom republish rate
  double transform_tolerance_sec = 0.1;  // tf stamped this far ahead of now
  double visualization_rate_hz = 2.0;    // max rate of ~path and ~graph_markers updates
  // ... and at least this many seconds per keyframe between two (visualizationPeriodSec).
  double visualization_period_per_keyframe_sec = 1e-4;
  double diagnostics_rate_hz = 1.0;
  int queue_size = 2000;              // input queue bound (messages beyond are dropped, counted)
  double service_timeout_sec = 60.0;  // a service waits this long for the worker
  // A graph saved by ~save_graph or autosave to resume on start; empty: start a new map.  A missing
  // file is a first run (logged); an unreadable or malformed one stops the node (it might be the
  // autosave of the map the user wants, which must not be overwritten).
  std::string load_path;
  // Where ~save_graph and ~load_graph read and write (names are relative to it; nothing outside it
  // is touched for a service) and what relative load_path / autosave_path are taken from.  "":
  // defaultGraphDirectory() ($ROS_HOME/toro_ros or ~/.ros/toro_ros); see pipeline/graph_directory.h.
  std::string graph_directory;
  // Threads of the finish's linear algebra (toro::setSolverThreads: OpenBLAS, OpenMP / CHOLMOD), set
  // once at start for the whole process (a nodelet: its manager and every nodelet in it); 0 leaves
  // the libraries' own.  1 by default: more threads made the finish slower beside other work on the
  // 2-core machines measured (bench/finish_load_results.md).
  int finish_threads = toro::kDefaultSolverThreads;
  PipelineOptions pipeline;
  MarkerOptions markers;
  InputHealthOptions diagnostics;  // when the diagnostics WARN or ERROR about the input
  std::string validate() const;
};

struct OptionsReport {
  std::vector<std::string> values;        // "key = value" for every known key (the log)
  std::vector<std::string> unknown_keys;  // keys given but not known (typos)
  std::vector<std::string> errors;        // wrong types or invalid values
};

// Reads every known key from `params` (a struct of the private namespace; missing keys keep their
// defaults).  Never throws: problems go to report->errors, and the options are only usable if
// that is empty.
NodeOptions loadNodeOptions(const XmlRpc::XmlRpcValue& params, OptionsReport* report);

// Every key loadNodeOptions knows.
std::set<std::string> knownParameterKeys();

}  // namespace toro_ros
