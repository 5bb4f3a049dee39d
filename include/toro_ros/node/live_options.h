// Run-time tuning: dynamic_reconfigure's MapCorrectorConfig (generated from cfg/MapCorrector.cfg)
// turned into the parameter struct loadNodeOptions reads, so a live change goes through the same
// reader and validation as the start-up parameters (no second parameter reader), and the list of
// what changed for the log.  No master needed: test/node/test_live_options.cpp.
#pragma once

#include <set>
#include <string>
#include <vector>

#include <xmlrpcpp/XmlRpcValue.h>

#include "toro_ros/MapCorrectorConfig.h"

namespace toro_ros {

// `params` (a struct of private parameters) with every parameter of `config` set to its value.
XmlRpc::XmlRpcValue withConfig(XmlRpc::XmlRpcValue params, const MapCorrectorConfig& config);

// "key: before -> after" for every known key whose value loadNodeOptions reads differently from
// the two parameter structs, in key order.
std::vector<std::string> changedParameters(const XmlRpc::XmlRpcValue& before,
                                           const XmlRpc::XmlRpcValue& after);

// The names of the parameters in cfg/MapCorrector.cfg.
std::set<std::string> liveParameterKeys();

}  // namespace toro_ros
