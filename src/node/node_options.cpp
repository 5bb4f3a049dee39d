#include "toro_ros/node/node_options.h"

#include <cmath>
#include <iomanip>
#include <optional>
#include <sstream>

namespace toro_ros {

namespace {

// Reads typed keys out of a struct value, remembering which keys it was asked for.
class ParamReader {
 public:
  ParamReader(const XmlRpc::XmlRpcValue& params, OptionsReport* report) : params_(params), report_(report) {}

  void read(const char* key, double& v) {
    readWith(
        key, v,
        [&](const XmlRpc::XmlRpcValue& x) {
          if (x.getType() == XmlRpc::XmlRpcValue::TypeDouble) return v = static_cast<double>(x), true;
          if (x.getType() == XmlRpc::XmlRpcValue::TypeInt) return v = static_cast<int>(x), true;
          return false;
        },
        "a number");
  }
  void read(const char* key, int& v) {
    readWith(
        key, v,
        [&](const XmlRpc::XmlRpcValue& x) {
          return x.getType() == XmlRpc::XmlRpcValue::TypeInt ? (v = static_cast<int>(x), true) : false;
        },
        "an integer");
  }
  void read(const char* key, std::size_t& v) {
    int i = static_cast<int>(v);
    read(key, i);
    if (i < 0) report_->errors.push_back(std::string(key) + ": must be >= 0, got " + std::to_string(i));
    v = static_cast<std::size_t>(std::max(i, 0));
  }
  void read(const char* key, bool& v) {
    readWith(
        key, v,
        [&](const XmlRpc::XmlRpcValue& x) {
          return x.getType() == XmlRpc::XmlRpcValue::TypeBoolean ? (v = static_cast<bool>(x), true) : false;
        },
        "true or false");
  }
  void read(const char* key, std::string& v) {
    readWith(
        key, v,
        [&](const XmlRpc::XmlRpcValue& x) {
          return x.getType() == XmlRpc::XmlRpcValue::TypeString ? (v = static_cast<std::string>(x), true)
                                                                : false;
        },
        "a string");
  }

  // An enumeration given as one of its names (`choices` lists them for the error).
  template <class E, class Parse>
  void readChoice(const char* key, E& v, Parse parse, const char* choices) {
    std::string text = toString(v);
    read(key, text);
    if (auto parsed = parse(text))
      v = *parsed;
    else
      report_->errors.push_back(std::string(key) + ": expected " + choices + ", got '" + text + "'");
  }

  void finish() {
    if (params_.getType() != XmlRpc::XmlRpcValue::TypeStruct) return;
    for (auto it = params_.begin(); it != params_.end(); ++it)
      if (known_.count(it->first) == 0) report_->unknown_keys.push_back(it->first);
  }

 private:
  template <class T, class F>
  void readWith(const char* key, T& v, F&& convert, const char* expected) {
    known_.insert(key);
    const bool given = params_.getType() == XmlRpc::XmlRpcValue::TypeStruct && params_.hasMember(key);
    if (given && !convert(params_[key])) {
      std::ostringstream got;
      params_[key].write(got);
      report_->errors.push_back(std::string(key) + ": expected " + expected + ", got '" + got.str() + "'");
    }
    std::ostringstream line;
    // 12 significant digits: enough for every value a user types, and live changes are found by
    // comparing these lines (live_options.cpp).
    line << key << " = " << std::boolalpha << std::setprecision(12) << v << (given ? "" : " (default)");
    report_->values.push_back(line.str());
  }

  // XmlRpcValue's const operator[] is missing in some versions; a copy is cheap for a few keys.
  XmlRpc::XmlRpcValue params_;
  OptionsReport* report_;
  std::set<std::string> known_;
};

// robust_kernel: a kernel that weighs ("none" is robust_loop_closures: false).
std::optional<toro::RobustKernel> robustKernelChoice(const std::string& name) {
  const auto kernel = toro::robustKernelFromString(name);
  if (!kernel || *kernel == toro::RobustKernel::kNone) return std::nullopt;
  return kernel;
}

void readPipeline(ParamReader& r, PipelineOptions& p) {
  r.read("keyframe_distance_m", p.keyframer.distance_m);
  r.read("keyframe_angle_rad", p.keyframer.angle_rad);
  r.read("keyframe_interval_sec", p.keyframer.interval_sec);
  r.readChoice("odometry_covariance_mode", p.keyframer.covariance_mode, odometryCovarianceModeFromString,
               "auto, difference, motion_scaled, latest or default");
  r.read("odometry_unmeasured_variance", p.keyframer.unmeasured_variance);
  r.read("odometry_default_translation_stddev_m", p.keyframer.default_stddev.translation_m);
  r.read("odometry_default_rotation_stddev_rad", p.keyframer.default_stddev.rotation_rad);
  r.read("loop_closure_stamp_tolerance_sec", p.matcher.stamp_tolerance_sec);
  r.read("loop_closure_max_pending", p.matcher.max_pending);
  r.read("loop_closure_creates_keyframes", p.matcher.create_keyframes);
  r.read("loop_closure_default_translation_stddev_m", p.loop_closure_default_stddev.translation_m);
  r.read("loop_closure_default_rotation_stddev_rad", p.loop_closure_default_stddev.rotation_rad);
  r.read("loop_closure_unmeasured_variance", p.loop_closure_unmeasured_variance);
  r.read("optimization_gamma", p.optimization.gamma);
  r.read("optimization_full_iterations", p.optimization.full_iterations);
  r.read("optimization_full_every_keyframes", p.optimization.full_every_keyframes);
  r.read("optimization_full_every_sec", p.optimization.full_every_sec);
  r.read("optimization_service_default_iterations", p.optimization.service_default_iterations);
  r.read("optimization_background_finish", p.optimization.background_finish);
  r.read("optimization_finish_min_interval_sec", p.optimization.finish_min_interval_sec);
  r.read("optimization_finish_max_iterations", p.optimization.finish_max_iterations);
  r.read("optimization_finish_chi2_tolerance", p.optimization.finish_chi2_tolerance);
  r.read("robust_hold_until_supported", p.optimization.hold_until_supported);
  r.read("robust_support_window_keyframes", p.optimization.support_window_keyframes);
  r.read("planar", p.planar);
  r.read("time_jump_reset_sec", p.time_jump_reset_sec);
  r.read("odometry_history_sec", p.odometry_history_sec);
  bool robust = p.robust.enabled();
  r.read("robust_loop_closures", robust);
  toro::RobustKernel kernel = p.robust.enabled() ? p.robust.kernel : toro::RobustKernel::kDcs;
  r.readChoice("robust_kernel", kernel, robustKernelChoice, "dcs, cauchy or huber");
  p.robust.kernel = robust ? kernel : toro::RobustKernel::kNone;
  r.read("robust_width", p.robust.width);
  r.read("robust_adaptive_width_factor", p.robust.adaptive_width_factor);
  r.read("loop_closure_gate_confidence", p.loop_closure_gate_confidence);
  r.read("loop_closure_gate_variance_factor", p.loop_closure_gate_variance_factor);
  r.read("autosave_path", p.persistence.autosave_path);
  r.read("autosave_period_sec", p.persistence.autosave_period_sec);
  r.readChoice("resume_link", p.persistence.resume_link, resumeLinkFromString, "continue or last_pose");
  r.read("resume_link_translation_stddev_m", p.persistence.resume_link_stddev.translation_m);
  r.read("resume_link_rotation_stddev_rad", p.persistence.resume_link_stddev.rotation_rad);
}

}  // namespace

std::string NodeOptions::validate() const {
  if (map_frame.empty() || odom_frame.empty() || map_frame == odom_frame)
    return "map_frame and odom_frame must be non-empty and different";
  if (!(tf_rate_hz > 0 && std::isfinite(tf_rate_hz))) return "tf_rate_hz must be > 0";
  if (!(transform_tolerance_sec >= 0 && std::isfinite(transform_tolerance_sec)))
    return "transform_tolerance_sec must be >= 0";
  if (!(visualization_rate_hz > 0 && std::isfinite(visualization_rate_hz)))
    return "visualization_rate_hz must be > 0";
  if (!(visualization_period_per_keyframe_sec >= 0 && std::isfinite(visualization_period_per_keyframe_sec)))
    return "visualization_period_per_keyframe_sec must be >= 0";
  if (!(diagnostics_rate_hz > 0 && std::isfinite(diagnostics_rate_hz)))
    return "diagnostics_rate_hz must be > 0";
  if (queue_size <= 0) return "queue_size must be > 0";
  if (!(service_timeout_sec > 0 && std::isfinite(service_timeout_sec)))
    return "service_timeout_sec must be > 0";
  if (const std::string e = toro::validateSolverThreads(finish_threads); !e.empty()) return "finish_threads: " + e;
  for (const std::string& e : {pipeline.validate(), markers.validate(), diagnostics.validate()})
    if (!e.empty()) return e;
  return "";
}

NodeOptions loadNodeOptions(const XmlRpc::XmlRpcValue& params, OptionsReport* report) {
  NodeOptions o;
  ParamReader r(params, report);
  r.read("map_frame", o.map_frame);
  r.read("odom_frame", o.odom_frame);
  r.read("tf_rate_hz", o.tf_rate_hz);
  r.read("transform_tolerance_sec", o.transform_tolerance_sec);
  r.read("visualization_rate_hz", o.visualization_rate_hz);
  r.read("visualization_period_per_keyframe_sec", o.visualization_period_per_keyframe_sec);
  r.read("diagnostics_rate_hz", o.diagnostics_rate_hz);
  r.read("queue_size", o.queue_size);
  r.read("service_timeout_sec", o.service_timeout_sec);
  r.read("load_path", o.load_path);
  r.read("graph_directory", o.graph_directory);
  r.read("finish_threads", o.finish_threads);
  readPipeline(r, o.pipeline);
  r.read("marker_node_scale_m", o.markers.node_scale_m);
  r.read("marker_edge_width_m", o.markers.edge_width_m);
  r.read("marker_loop_closure_chi2_red", o.markers.loop_closure_chi2_red);
  r.read("marker_draw_odometry_edges", o.markers.draw_odometry_edges);
  r.read("diagnostics_stale_odometry_sec", o.diagnostics.stale_odometry_sec);
  r.read("diagnostics_max_refusals_per_sec", o.diagnostics.max_refusals_per_sec);
  r.finish();
  o.pipeline.odom_frame = o.odom_frame;  // the pipeline refuses odometry in another frame
  if (report->errors.empty()) {
    const std::string invalid = o.validate();
    if (!invalid.empty()) report->errors.push_back(invalid);
  }
  return o;
}

std::set<std::string> knownParameterKeys() {
  OptionsReport report;
  loadNodeOptions(XmlRpc::XmlRpcValue(), &report);
  std::set<std::string> keys;
  for (const std::string& line : report.values) keys.insert(line.substr(0, line.find(' ')));
  return keys;
}

}  // namespace toro_ros
