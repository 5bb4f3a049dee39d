#include "toro_ros/offline/flat_yaml.h"

#include <cerrno>
#include <cstdlib>
#include <fstream>
#include <stdexcept>

namespace toro_ros {
namespace offline {

namespace {

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r");
  if (b == std::string::npos) return "";
  return s.substr(b, s.find_last_not_of(" \t\r") - b + 1);
}

// Strips a trailing comment that is not inside quotes.
std::string withoutComment(const std::string& s) {
  char quote = 0;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (quote) {
      if (s[i] == quote) quote = 0;
    } else if (s[i] == '"' || s[i] == '\'') {
      quote = s[i];
    } else if (s[i] == '#' && (i == 0 || s[i - 1] == ' ' || s[i - 1] == '\t')) {
      return s.substr(0, i);
    }
  }
  return s;
}

XmlRpc::XmlRpcValue scalar(const std::string& text) {
  if (text == "true" || text == "True") return XmlRpc::XmlRpcValue(true);
  if (text == "false" || text == "False") return XmlRpc::XmlRpcValue(false);
  if (text.size() >= 2 && (text.front() == '"' || text.front() == '\'') && text.back() == text.front())
    return XmlRpc::XmlRpcValue(text.substr(1, text.size() - 2));
  char* end = nullptr;
  errno = 0;
  const long i = std::strtol(text.c_str(), &end, 10);
  if (end && *end == '\0' && errno == 0 && i >= INT32_MIN && i <= INT32_MAX)
    return XmlRpc::XmlRpcValue(static_cast<int>(i));
  const double d = std::strtod(text.c_str(), &end);
  if (end && *end == '\0' && !text.empty()) return XmlRpc::XmlRpcValue(d);
  return XmlRpc::XmlRpcValue(text);
}

}  // namespace

XmlRpc::XmlRpcValue readFlatYaml(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot open the parameter file");
  XmlRpc::XmlRpcValue out;
  out.begin();  // makes it an (empty) struct
  std::string line;
  for (std::size_t number = 1; std::getline(in, line); ++number) {
    const std::string content = trim(withoutComment(line));
    if (content.empty() || content == "---") continue;
    const std::string where = path + ":" + std::to_string(number) + ": ";
    if (line[0] == ' ' || line[0] == '\t' || content[0] == '-')
      throw std::runtime_error(where + "nested maps and lists are not supported (flat key: value only)");
    const auto colon = content.find(':');
    if (colon == std::string::npos) throw std::runtime_error(where + "expected 'key: value'");
    const std::string key = trim(content.substr(0, colon)), value = trim(content.substr(colon + 1));
    if (key.empty() || value.empty())
      throw std::runtime_error(where + "expected 'key: value' with both parts");
    if (out.hasMember(key)) throw std::runtime_error(where + "key '" + key + "' given twice");
    out[key] = scalar(value);
  }
  return out;
}

}  // namespace offline
}  // namespace toro_ros
