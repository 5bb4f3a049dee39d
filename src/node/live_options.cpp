#include "toro_ros/node/live_options.h"

#include <map>

#include <boost/any.hpp>

#include "toro_ros/node/node_options.h"

namespace toro_ros {

namespace {

// key -> value as loadNodeOptions logs it ("key = value" or "key = value (default)").
std::map<std::string, std::string> readValues(const XmlRpc::XmlRpcValue& params) {
  OptionsReport report;
  loadNodeOptions(params, &report);
  std::map<std::string, std::string> values;
  const std::string kDefault = " (default)";
  for (std::string line : report.values) {
    const std::size_t eq = line.find(" = ");
    if (eq == std::string::npos) continue;
    if (line.size() >= kDefault.size() &&
        line.compare(line.size() - kDefault.size(), kDefault.size(), kDefault) == 0)
      line.resize(line.size() - kDefault.size());
    values[line.substr(0, eq)] = line.substr(eq + 3);
  }
  return values;
}

}  // namespace

XmlRpc::XmlRpcValue withConfig(XmlRpc::XmlRpcValue params, const MapCorrectorConfig& config) {
  if (params.getType() != XmlRpc::XmlRpcValue::TypeStruct) params = XmlRpc::XmlRpcValue();
  for (const auto& description : MapCorrectorConfig::__getParamDescriptions__()) {
    boost::any value;
    description->getValue(config, value);
    if (description->type == "double")
      params[description->name] = boost::any_cast<double>(value);
    else if (description->type == "int")
      params[description->name] = boost::any_cast<int>(value);
    else if (description->type == "bool")
      params[description->name] = boost::any_cast<bool>(value);
    else
      params[description->name] = boost::any_cast<std::string>(value);
  }
  return params;
}

std::vector<std::string> changedParameters(const XmlRpc::XmlRpcValue& before,
                                           const XmlRpc::XmlRpcValue& after) {
  const std::map<std::string, std::string> a = readValues(before), b = readValues(after);
  std::vector<std::string> changes;
  for (const auto& [key, value] : b) {
    const auto it = a.find(key);
    if (it != a.end() && it->second != value) changes.push_back(key + ": " + it->second + " -> " + value);
  }
  return changes;
}

std::set<std::string> liveParameterKeys() {
  std::set<std::string> keys;
  for (const auto& description : MapCorrectorConfig::__getParamDescriptions__())
    keys.insert(description->name);
  return keys;
}

}  // namespace toro_ros
