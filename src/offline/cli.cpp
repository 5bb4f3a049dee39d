#include "toro_ros/offline/cli.h"

#include <cstdlib>
#include <sstream>
#include <stdexcept>

namespace toro_ros {
namespace offline {

ParsedArgs parseArgs(int argc, char** argv, const std::vector<ArgSpec>& specs) {
  ParsedArgs out;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "-h" || arg == "--help") {
      out.help = true;
      continue;
    }
    if (arg.rfind("--", 0) != 0 || arg.size() == 2) {
      out.positional.push_back(arg);
      continue;
    }
    const std::string name = arg.substr(2);
    const ArgSpec* spec = nullptr;
    for (const ArgSpec& s : specs)
      if (s.name == name) spec = &s;
    if (!spec) throw std::invalid_argument("unknown option " + arg + " (see --help)");
    if (!spec->takes_value) {
      out.values[name] = "true";
      continue;
    }
    if (i + 1 >= argc) throw std::invalid_argument(arg + ": missing value");
    out.values[name] = argv[++i];
  }
  return out;
}

double ParsedArgs::number(const std::string& name, double fallback) const {
  const auto it = values.find(name);
  if (it == values.end()) return fallback;
  char* end = nullptr;
  const double v = std::strtod(it->second.c_str(), &end);
  if (it->second.empty() || *end != '\0')
    throw std::invalid_argument("--" + name + ": expected a number, got '" + it->second + "'");
  return v;
}

int ParsedArgs::integer(const std::string& name, int fallback) const {
  const auto it = values.find(name);
  if (it == values.end()) return fallback;
  char* end = nullptr;
  const long v = std::strtol(it->second.c_str(), &end, 10);
  if (it->second.empty() || *end != '\0' || v < -1000000000L || v > 1000000000L)
    throw std::invalid_argument("--" + name + ": expected an integer, got '" + it->second + "'");
  return static_cast<int>(v);
}

std::string ParsedArgs::text(const std::string& name, const std::string& fallback) const {
  const auto it = values.find(name);
  return it == values.end() ? fallback : it->second;
}

std::string usage(const std::string& synopsis, const std::vector<ArgSpec>& specs) {
  std::ostringstream out;
  out << "usage: " << synopsis << "\n";
  for (const ArgSpec& s : specs)
    out << "  --" << s.name << (s.takes_value ? " VALUE" : "") << "\n      " << s.help << "\n";
  return out.str();
}

}  // namespace offline
}  // namespace toro_ros
