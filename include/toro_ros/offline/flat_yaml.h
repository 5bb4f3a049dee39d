// A reader for the node's parameter files (config/*.yaml) without a master: they are flat
// "key: value" maps, which is all this reads (nested maps and lists are refused with the line).
#pragma once

#include <string>

#include <xmlrpcpp/XmlRpcValue.h>

namespace toro_ros {
namespace offline {

// Values become XmlRpc booleans (true/false), ints, doubles or strings (quotes removed), as
// rosparam would load them.  Throws std::runtime_error "path:line: why".
XmlRpc::XmlRpcValue readFlatYaml(const std::string& path);

}  // namespace offline
}  // namespace toro_ros
