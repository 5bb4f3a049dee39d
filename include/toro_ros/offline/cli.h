// Command lines of the offline tools: "--name value" options, "--flag" switches and positional
// arguments, with errors that name the option.
#pragma once

#include <map>
#include <string>
#include <vector>

namespace toro_ros {
namespace offline {

struct ArgSpec {
  std::string name;  // without the leading "--"
  std::string help;
  bool takes_value = true;
};

struct ParsedArgs {
  std::map<std::string, std::string> values;  // switches map to "true"
  std::vector<std::string> positional;
  bool help = false;  // -h / --help given
  bool has(const std::string& name) const { return values.count(name) != 0; }
  // Typed access; throw std::invalid_argument "--name: expected ..., got 'x'".
  double number(const std::string& name, double fallback) const;
  int integer(const std::string& name, int fallback) const;
  std::string text(const std::string& name, const std::string& fallback) const;
};

// Throws std::invalid_argument for an unknown option or a missing value.
ParsedArgs parseArgs(int argc, char** argv, const std::vector<ArgSpec>& specs);
std::string usage(const std::string& synopsis, const std::vector<ArgSpec>& specs);

}  // namespace offline
}  // namespace toro_ros
