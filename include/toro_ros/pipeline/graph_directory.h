// The directory of a node's graph files (graph_directory) and the one place that turns a name
// from a service caller into a file in it.  ROS 1 has no authentication: ~save_graph and
// ~load_graph answer anyone on the ROS network, so a name must not reach a file outside the
// directory, and a save must not destroy a file that is not a graph.
//
// A name is refused, with nothing read or written, when
//  - it is empty or holds a control character;
//  - it (or, through symbolic links, the file it leads to) has no graph extension (.g2o, .graph,
//    .toro; the format follows it);
//  - it resolves outside the directory: an absolute path elsewhere, ".." leading out, a symbolic
//    link (to a file or a directory, anywhere on the way) leading out.  Resolution follows
//    std::filesystem::weakly_canonical (realpath for what exists), and the directory itself is
//    canonical, so a graph_directory reached through a link of the operator's works;
//  - for a save: what is at it, or at its sidecar "<name>.stamps", is not a graph (resp. a
//    keyframe sidecar) file, see checkReplaceable.
// Between the check and the read or write nothing is resolved again: the directory holding the file
// is opened component by component without following links and kept open (GraphFileRef).
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include "toro_ros/pipeline/graph_file.h"

namespace toro_ros {

// $ROS_HOME/toro_ros, else ~/.ros/toro_ros (where ROS keeps its own files).
std::string defaultGraphDirectory();

// A file for a service, or why not.
struct ConfinedFile {
  std::optional<GraphFileRef> file;
  std::string error;  // empty when `file` is set
};

class GraphDirectory {
 public:
  // `path`: "" for defaultGraphDirectory(); a relative one is taken from the working directory.
  // Nothing on disk is touched here: the directory is created when a file is to go into it.
  explicit GraphDirectory(const std::string& path = "");

  const std::string& path() const { return path_; }  // absolute, lexically normal

  // ~load_graph's and ~save_graph's name (relative to the directory, or absolute inside it).
  // Errors name the caller's name and the directory and say why, never the content of a file nor
  // where a link leads.  forSave creates the directory when missing.
  ConfinedFile forLoad(const std::string& name) const;
  ConfinedFile forSave(const std::string& name) const;

  // The operator's load_path and autosave_path (trusted: they may lie anywhere): relative ones are
  // taken from the directory (which is then created, for the autosave), and both are resolved
  // through symbolic links, so an autosave through a link replaces the file it leads to, not the
  // link.  "" stays "" (off).  Returns the start-up log line naming the directory and both paths.
  // Throws std::runtime_error if the directory is needed and cannot be created.
  std::string resolveOperatorPaths(std::string* load_path, std::string* autosave_path) const;

 private:
  // Empty if `name` may be used (then *resolved is its file, below *root, both canonical), else why not.
  std::string check(const std::string& name, std::filesystem::path* root,
                    std::filesystem::path* resolved) const;
  ConfinedFile resolve(const std::string& name, bool for_save) const;
  void create() const;

  std::string path_;
};

}  // namespace toro_ros
