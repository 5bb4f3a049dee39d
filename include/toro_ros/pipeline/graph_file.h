// A graph file (or its sidecar) as the pipeline reads and writes it, and the file operations on
// it.  Two kinds of reference:
//  - an operator's path (autosave_path, load_path, toro_offline's outputs, tests): resolved by the
//    system as any path is, symbolic links followed; error messages may quote a short excerpt of
//    the file, as the core's readers do (it is the operator's own file);
//  - a file inside the graph directory, made by GraphDirectory for the node's services: the
//    directory that holds it is kept open, so what GraphDirectory checked is what is read or
//    written (no path is resolved again: a directory on the way swapped for a symbolic link after
//    the check is not followed); the file itself is opened without following a symbolic link;
//    and error messages never quote the file's content (ParseError::redactedWhat), since the
//    service's caller is anyone on the ROS network.
#pragma once

#include <functional>
#include <iosfwd>
#include <memory>
#include <string>

#include "toro_ros/core/graph_io.h"

namespace toro_ros {

// Owns a file descriptor (closed on destruction).
class FileDescriptor {
 public:
  explicit FileDescriptor(int fd) : fd_(fd) {}
  ~FileDescriptor();
  FileDescriptor(FileDescriptor&& other) noexcept : fd_(other.fd_) { other.fd_ = -1; }
  FileDescriptor(const FileDescriptor&) = delete;
  FileDescriptor& operator=(const FileDescriptor&) = delete;
  int get() const { return fd_; }

 private:
  int fd_;
};

class GraphFileRef {
 public:
  // An operator's path (relative ones from the working directory).  `quote_content` false: error
  // messages about it do not quote it either (the node's log goes to /rosout, which anyone on the
  // ROS network reads).
  explicit GraphFileRef(std::string path, bool quote_content = true);
  // `name` (one path component) in the open `directory`; `display_path` names it in messages.
  GraphFileRef(std::shared_ptr<const FileDescriptor> directory, std::string name, std::string display_path);

  // "<file>.stamps" beside it, of the same kind.
  GraphFileRef sidecar() const;
  // True for a file in the graph directory: symbolic links not followed, content never quoted.
  bool confined() const { return directory_ != nullptr; }
  // What openat()/renameat() take: the open directory, or AT_FDCWD for an operator's path.
  int directoryFd() const;
  const std::string& name() const { return name_; }
  const std::string& displayPath() const { return display_path_; }
  // The message of a ParseError about this file: without the file's content when confined() or
  // made with quote_content false.
  std::string describe(const toro::ParseError& error) const;

 private:
  std::shared_ptr<const FileDescriptor> directory_;
  std::string name_;
  std::string display_path_;
  bool quote_content_ = false;
};

// Whether anything (a symbolic link too, dangling or not) is at the file's name.
bool fileExists(const GraphFileRef& file);

// Opens the file for reading: a regular file only (a FIFO or device would block or never end).
// Throws toro::ParseError(displayPath, 0, why) naming the file.
FileDescriptor openForReading(const GraphFileRef& file);
// The core's reader on the file (format by the extension of its name).  Throws toro::ParseError.
toro::PoseGraph readGraphFile(const GraphFileRef& file, const toro::ReadOptions& options = {},
                              toro::ReadReport* report = nullptr);

// A file written under a temporary name beside its final one and renamed over it by commit(), so
// that a crash or kill leaves the old file or the new one, never a partial one.  The temporary is
// created exclusively (never through a symbolic link), fsync'ed before the rename, and the
// directory is synced after it.  Destroyed before commit(), the temporary is removed.
class PendingFile {
 public:
  // Writes the temporary with `write`.  Throws std::runtime_error naming the file.
  PendingFile(const GraphFileRef& file, const std::function<void(std::ostream&)>& write);
  ~PendingFile();
  PendingFile(const PendingFile&) = delete;
  PendingFile& operator=(const PendingFile&) = delete;
  // Renames the temporary over the file.  Throws std::runtime_error naming the file.
  void commit();

 private:
  GraphFileRef file_;
  std::string temporary_;
  bool committed_ = false;
};

// A temporary name in the same directory with the same extension (the graph format goes by it):
// "dir/name.g2o" -> "dir/.name.tmp<pid>.g2o".
std::string temporaryPath(const std::string& path);

}  // namespace toro_ros
