#include "toro_ros/pipeline/graph_directory.h"

#include <fcntl.h>
#include <pwd.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <memory>
#include <stdexcept>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/pipeline/persistence.h"

namespace toro_ros {

namespace {

namespace fs = std::filesystem;

// "a/b/" -> "a/b", lexically normal.
fs::path normalDirectory(const fs::path& p) {
  fs::path n = p.lexically_normal();
  if (n.has_relative_path() && n.filename().empty()) n = n.parent_path();
  return n;
}

// Whether `p` lies strictly below `root` (both absolute and normal).
bool inside(const fs::path& p, const fs::path& root) {
  auto q = p.begin();
  for (auto r = root.begin(); r != root.end(); ++r, ++q)
    if (q == p.end() || *q != *r) return false;
  return q != p.end();
}

bool hasControlCharacter(const std::string& s) {
  return std::any_of(s.begin(), s.end(), [](char c) {
    const auto u = static_cast<unsigned char>(c);
    return u < 0x20 || u == 0x7f;
  });
}

bool hasGraphExtension(const fs::path& p) {
  return toro::formatFromExtension(p.filename().string()) != toro::GraphFormat::kAuto;
}

// The caller's own name, quoted for a message (control characters were refused before).
std::string quote(const std::string& name) {
  constexpr std::size_t kMax = 200;
  return "'" + name.substr(0, kMax) + (name.size() > kMax ? "...'" : "'");
}

ConfinedFile refused(const std::string& why) { return ConfinedFile{std::nullopt, why}; }

}  // namespace

std::string defaultGraphDirectory() {
  const char* ros_home = std::getenv("ROS_HOME");
  if (ros_home != nullptr && *ros_home != '\0') return (fs::path(ros_home) / "toro_ros").string();
  std::string home;
  if (const char* h = std::getenv("HOME"); h != nullptr) home = h;
  if (home.empty())
    if (const passwd* pw = ::getpwuid(::getuid()); pw != nullptr && pw->pw_dir != nullptr) home = pw->pw_dir;
  return (fs::path(home.empty() ? "." : home) / ".ros" / "toro_ros").string();
}

GraphDirectory::GraphDirectory(const std::string& path)
    : path_(normalDirectory(fs::absolute(path.empty() ? defaultGraphDirectory() : path)).string()) {}

void GraphDirectory::create() const {
  std::error_code ec;
  fs::create_directories(path_, ec);
  if (ec) throw std::runtime_error("cannot create graph_directory " + path_ + ": " + ec.message());
}

ConfinedFile GraphDirectory::forLoad(const std::string& name) const { return resolve(name, false); }

ConfinedFile GraphDirectory::forSave(const std::string& name) const { return resolve(name, true); }

std::string GraphDirectory::check(const std::string& name, fs::path* root, fs::path* resolved) const {
  if (name.empty())
    return "no file name given: give the name of a graph file in graph_directory " + path_ + ", e.g. map.g2o";
  if (hasControlCharacter(name)) return "the file name contains a control character: refused";
  const std::string shown = quote(name);
  const fs::path given(name);
  const fs::path joined = given.is_absolute() ? given : fs::path(path_) / given;
  // Both resolved as the system would (links followed, ".." after a link taken from its target);
  // the directory too, as it may not exist yet.
  std::error_code ec;
  *root = fs::weakly_canonical(path_, ec);
  if (ec) return shown + ": graph_directory " + path_ + " cannot be resolved: " + ec.message();
  *resolved = fs::weakly_canonical(joined, ec);
  if (ec) return shown + " cannot be resolved: " + ec.message();
  if (!inside(*resolved, *root)) {
    const fs::path lexical = joined.lexically_normal();
    if (inside(lexical, fs::path(path_)) || inside(lexical, *root))
      return shown + " leads outside graph_directory " + path_ + " through a symbolic link: refused";
    return shown + " is outside graph_directory " + path_ +
           ": refused (give a name relative to it; '..' may not leave it)";
  }
  if (!hasGraphExtension(given))
    return shown + " is not a graph file name: refused (.g2o, .graph or .toro; the format follows it)";
  if (!hasGraphExtension(*resolved))
    return shown + " is a symbolic link to a file without a graph extension: refused";
  // weakly_canonical keeps a link that leads to nothing as it is (it cannot resolve it).
  std::error_code ignored;  // a missing component is not a link
  fs::path prefix = *root;
  for (const fs::path& part : resolved->lexically_relative(*root)) {
    prefix /= part;
    if (fs::is_symlink(prefix, ignored))
      return shown + " goes through a symbolic link to a missing file or directory: refused";
  }
  return "";
}

ConfinedFile GraphDirectory::resolve(const std::string& name, bool for_save) const {
  fs::path root, resolved;
  const std::string error = check(name, &root, &resolved);
  if (!error.empty()) return refused(error);
  const std::string shown = quote(name);
  if (for_save) {
    try {
      create();
    } catch (const std::exception& e) {
      return refused(e.what());
    }
  }
  std::error_code ec;
  if (fs::canonical(path_, ec) != root)
    return refused(shown + ": graph_directory " + path_ +
                   (ec ? " does not exist yet" : " changed while it was checked"));
  // Open the directory that holds the file, one component at a time without following links:
  // `resolved` has none, so a link found now appeared after the check.
  const fs::path relative = resolved.lexically_relative(root);
  auto directory =
      std::make_shared<const FileDescriptor>(::open(root.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC));
  if (directory->get() < 0)
    return refused("cannot open graph_directory " + path_ + ": " + std::strerror(errno));
  fs::path walked;
  for (const fs::path& part : relative.parent_path()) {
    walked /= part;
    auto next = std::make_shared<const FileDescriptor>(
        ::openat(directory->get(), part.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC));
    if (next->get() < 0) {
      const int err = errno;
      if (err == ENOENT)
        return refused(shown + ": there is no directory " + walked.string() + " in graph_directory " + path_);
      if (err == ELOOP || err == ENOTDIR)
        return refused(shown + ": " + walked.string() +
                       " changed while it was checked (a link or not a directory now): refused");
      return refused(shown + ": cannot open " + walked.string() + ": " + std::strerror(err));
    }
    directory = std::move(next);
  }
  GraphFileRef file(directory, relative.filename().string(), resolved.string());
  if (for_save) {
    const std::string why = checkReplaceable(file);
    if (!why.empty()) return refused("refusing to replace " + shown + ": " + why);
  }
  return ConfinedFile{std::move(file), ""};
}

std::string GraphDirectory::resolveOperatorPaths(std::string* load_path, std::string* autosave_path) const {
  const auto resolve = [this](std::string* p) {
    if (p->empty()) return;
    fs::path given(*p);
    if (given.is_relative()) {
      create();
      given = fs::path(path_) / given;
    }
    std::error_code ec;
    fs::path resolved = fs::weakly_canonical(given, ec);
    // weakly_canonical keeps a link to a file that does not exist yet: follow it by hand (as the
    // kernel does, at most 40 times).
    std::error_code no_link;  // is_symlink of a missing file reports ENOENT: not a link
    for (int hops = 0; !ec && hops < 40 && fs::is_symlink(resolved, no_link); ++hops) {
      const fs::path target = fs::read_symlink(resolved, ec);
      if (!ec)
        resolved = fs::weakly_canonical(target.is_absolute() ? target : resolved.parent_path() / target, ec);
    }
    *p = (ec ? fs::absolute(given).lexically_normal() : resolved).string();
  };
  resolve(load_path);
  resolve(autosave_path);
  const auto shown = [](const std::string& p) { return p.empty() ? std::string("off") : p; };
  return "graph files: graph_directory " + path_ +
         " (names given to ~save_graph and ~load_graph are relative to it; nothing outside it is read or "
         "written for them); load_path " +
         shown(*load_path) + "; autosave_path " + shown(*autosave_path);
}

}  // namespace toro_ros
