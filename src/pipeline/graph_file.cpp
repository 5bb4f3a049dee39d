// File operations on a GraphFileRef: everything goes through openat/renameat on the reference's
// directory, so a confined file is read and written exactly where GraphDirectory checked it.
#include "toro_ros/pipeline/graph_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstring>
#include <istream>
#include <ostream>
#include <stdexcept>
#include <streambuf>

namespace toro_ros {

namespace {

// A buffered stream over a file descriptor it does not own (reading or writing, not both).
class FdStreamBuf : public std::streambuf {
 public:
  explicit FdStreamBuf(int fd) : fd_(fd) { setp(buffer_.data(), buffer_.data() + buffer_.size()); }
  int error() const { return error_; }

 protected:
  int_type underflow() override {
    ssize_t n;
    do n = ::read(fd_, buffer_.data(), buffer_.size());
    while (n < 0 && errno == EINTR);
    if (n <= 0) {
      if (n < 0) error_ = errno;
      return traits_type::eof();
    }
    setg(buffer_.data(), buffer_.data(), buffer_.data() + n);
    return traits_type::to_int_type(buffer_[0]);
  }
  int_type overflow(int_type c) override {
    if (!flushBuffer()) return traits_type::eof();
    if (!traits_type::eq_int_type(c, traits_type::eof())) sputc(traits_type::to_char_type(c));
    return traits_type::not_eof(c);
  }
  int sync() override { return flushBuffer() ? 0 : -1; }

 private:
  bool flushBuffer() {
    for (char* p = pbase(); p < pptr();) {
      const ssize_t n = ::write(fd_, p, static_cast<std::size_t>(pptr() - p));
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        error_ = n < 0 ? errno : EIO;
        return false;
      }
      p += n;
    }
    setp(buffer_.data(), buffer_.data() + buffer_.size());
    return true;
  }

  int fd_;
  int error_ = 0;
  std::array<char, 1 << 16> buffer_;
};

// The directory part of a name relative to a directory fd ("." for a bare name).
std::string parentOf(const std::string& name) {
  const std::size_t slash = name.find_last_of('/');
  if (slash == std::string::npos) return ".";
  return slash == 0 ? "/" : name.substr(0, slash);
}

std::runtime_error fileError(const GraphFileRef& file, const std::string& what, int err) {
  return std::runtime_error(file.displayPath() + ": " + what + ": " + std::strerror(err));
}

}  // namespace

FileDescriptor::~FileDescriptor() {
  if (fd_ >= 0) ::close(fd_);
}

GraphFileRef::GraphFileRef(std::string path, bool quote_content)
    : name_(path), display_path_(std::move(path)), quote_content_(quote_content) {}

GraphFileRef::GraphFileRef(std::shared_ptr<const FileDescriptor> directory, std::string name,
                           std::string display_path)
    : directory_(std::move(directory)), name_(std::move(name)), display_path_(std::move(display_path)) {}

GraphFileRef GraphFileRef::sidecar() const {
  GraphFileRef s = *this;
  s.name_ += ".stamps";
  s.display_path_ += ".stamps";
  return s;
}

int GraphFileRef::directoryFd() const { return directory_ ? directory_->get() : AT_FDCWD; }

std::string GraphFileRef::describe(const toro::ParseError& error) const {
  return quote_content_ ? error.what() : error.redactedWhat();
}

bool fileExists(const GraphFileRef& file) {
  struct stat st;
  return ::fstatat(file.directoryFd(), file.name().c_str(), &st, AT_SYMLINK_NOFOLLOW) == 0;
}

FileDescriptor openForReading(const GraphFileRef& file) {
  // O_NONBLOCK: opening a FIFO must not wait for a writer (it is refused below).
  const int flags = O_RDONLY | O_CLOEXEC | O_NONBLOCK | (file.confined() ? O_NOFOLLOW : 0);
  FileDescriptor fd(::openat(file.directoryFd(), file.name().c_str(), flags));
  if (fd.get() < 0) {
    const int err = errno;
    if (err == ELOOP && file.confined())
      throw toro::ParseError(file.displayPath(), 0, "is a symbolic link (not followed in graph_directory)");
    throw toro::ParseError(file.displayPath(), 0,
                           std::string("cannot open for reading: ") + std::strerror(err));
  }
  struct stat st;
  if (::fstat(fd.get(), &st) != 0)
    throw toro::ParseError(file.displayPath(), 0, std::string("cannot stat: ") + std::strerror(errno));
  if (S_ISDIR(st.st_mode)) throw toro::ParseError(file.displayPath(), 0, "is a directory, not a graph file");
  if (!S_ISREG(st.st_mode)) throw toro::ParseError(file.displayPath(), 0, "is not a regular file");
  ::fcntl(fd.get(), F_SETFL, ::fcntl(fd.get(), F_GETFL) & ~O_NONBLOCK);
  return fd;
}

toro::PoseGraph readGraphFile(const GraphFileRef& file, const toro::ReadOptions& options,
                              toro::ReadReport* report) {
  const FileDescriptor fd = openForReading(file);
  FdStreamBuf buffer(fd.get());
  std::istream in(&buffer);
  toro::PoseGraph graph = toro::readGraph(in, file.displayPath(), options, report);
  if (buffer.error() != 0)
    throw toro::ParseError(file.displayPath(), 0,
                           std::string("read error: ") + std::strerror(buffer.error()));
  return graph;
}

std::string temporaryPath(const std::string& path) {
  const std::size_t slash = path.find_last_of('/');
  const std::string dir = slash == std::string::npos ? "" : path.substr(0, slash + 1);
  const std::string name = path.substr(dir.size());
  const std::size_t dot = name.find_last_of('.');
  const std::string stem = dot == std::string::npos || dot == 0 ? name : name.substr(0, dot);
  const std::string ext = dot == std::string::npos || dot == 0 ? "" : name.substr(dot);
  return dir + "." + stem + ".tmp" + std::to_string(::getpid()) + ext;
}

PendingFile::PendingFile(const GraphFileRef& file, const std::function<void(std::ostream&)>& write)
    : file_(file), temporary_(temporaryPath(file.name())) {
  const int dir = file_.directoryFd();
  const int flags = O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC;
  int fd = ::openat(dir, temporary_.c_str(), flags, 0666);
  if (fd < 0 && errno == EEXIST) {
    // Left by a process with our pid that died while saving (the names are per pid).
    ::unlinkat(dir, temporary_.c_str(), 0);
    fd = ::openat(dir, temporary_.c_str(), flags, 0666);
  }
  if (fd < 0) throw fileError(file_, "cannot create a temporary file beside it", errno);
  const FileDescriptor owned(fd);
  int err = 0;
  try {
    FdStreamBuf buffer(fd);
    std::ostream out(&buffer);
    write(out);
    out.flush();
    if (!out) err = buffer.error() != 0 ? buffer.error() : EIO;
  } catch (...) {
    ::unlinkat(dir, temporary_.c_str(), 0);
    throw;
  }
  if (err == 0 && ::fsync(fd) != 0) err = errno;
  if (err != 0) {
    ::unlinkat(dir, temporary_.c_str(), 0);
    throw fileError(file_, "write failed", err);
  }
}

PendingFile::~PendingFile() {
  if (!committed_) ::unlinkat(file_.directoryFd(), temporary_.c_str(), 0);
}

void PendingFile::commit() {
  const int dir = file_.directoryFd();
  if (::renameat(dir, temporary_.c_str(), dir, file_.name().c_str()) != 0)
    throw fileError(file_, "cannot rename the temporary file over it", errno);
  committed_ = true;
  const FileDescriptor parent(
      ::openat(dir, parentOf(file_.name()).c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC));
  if (parent.get() < 0 || ::fsync(parent.get()) != 0)
    throw fileError(file_, "cannot sync its directory", errno);
}

}  // namespace toro_ros
