#include "toro_ros/pipeline/persistence.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <iomanip>
#include <sstream>
#include <stdexcept>

namespace toro_ros {

namespace {
// The first line of every sidecar writeSidecar writes (then " v1").
constexpr const char* kSidecarHeader = "# toro_ros keyframe sidecar";
}  // namespace

std::string sidecarPath(const std::string& graph_path) { return graph_path + ".stamps"; }

void writeSidecar(const std::string& path, const Sidecar& sidecar) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error(path + ": cannot open for writing");
  writeSidecar(out, sidecar);
  if (!out) throw std::runtime_error(path + ": write failed");
}

void writeSidecar(std::ostream& out, const Sidecar& sidecar) {
  out << kSidecarHeader << " v1\n# KEYFRAME id sec nsec x y z qx qy qz qw (odom_T_base)\n"
      << "# LOOP_CLOSURE constraint_index\n"
      << std::setprecision(17);
  for (const KeyframeRecord& k : sidecar.keyframes) {
    const auto& t = k.odom_T_base.translation();
    const auto& q = k.odom_T_base.rotation();
    out << "KEYFRAME " << k.id << ' ' << k.stamp.sec << ' ' << k.stamp.nsec << ' ' << t.x() << ' ' << t.y()
        << ' ' << t.z() << ' ' << q.x() << ' ' << q.y() << ' ' << q.z() << ' ' << q.w() << '\n';
  }
  for (std::size_t c : sidecar.loop_closures) out << "LOOP_CLOSURE " << c << '\n';
  for (const RejectedLoopClosure& r : sidecar.rejected) {
    const toro::Constraint& c = r.constraint;
    const auto& t = c.measurement.translation();
    const auto& q = c.measurement.rotation();
    out << "REJECTED " << c.from << ' ' << c.to << ' ' << r.stamp.sec << ' ' << r.stamp.nsec << ' ' << r.chi2
        << ' ' << t.x() << ' ' << t.y() << ' ' << t.z() << ' ' << q.x() << ' ' << q.y() << ' ' << q.z() << ' '
        << q.w();
    for (int i = 0; i < 6; ++i)
      for (int j = i; j < 6; ++j) out << ' ' << c.information(i, j);
    out << '\n';
  }
}

namespace {

// A line of a sidecar, for errors.
struct Where {
  const std::string& source;
  std::size_t line;
  [[noreturn]] void fail(const std::string& message, const std::string& redacted = "") const {
    throw toro::ParseError(source, line, message, redacted);
  }
};

KeyframeRecord parseKeyframe(std::istringstream& in, const Where& where) {
  KeyframeRecord k;
  long long sec = 0, nsec = 0;
  double x, y, z, qx, qy, qz, qw;
  if (!(in >> k.id >> sec >> nsec >> x >> y >> z >> qx >> qy >> qz >> qw))
    where.fail("KEYFRAME needs id sec nsec x y z qx qy qz qw");
  if (sec < 0 || nsec < 0 || nsec >= 1000000000LL || sec > 0xffffffffLL)
    where.fail("stamp out of range");
  k.stamp = ros::Time(static_cast<uint32_t>(sec), static_cast<uint32_t>(nsec));
  k.odom_T_base = toro::Pose3(toro::Quaternion(qw, qx, qy, qz), toro::Vector3(x, y, z));
  if (!k.odom_T_base.isFinite()) where.fail("pose is not finite");
  return k;
}

RejectedLoopClosure parseRejected(std::istringstream& in, const Where& where) {
  RejectedLoopClosure r;
  long long sec = 0, nsec = 0;
  double x, y, z, qx, qy, qz, qw;
  if (!(in >> r.constraint.from >> r.constraint.to >> sec >> nsec >> r.chi2 >> x >> y >> z >> qx >> qy >> qz >> qw))
    where.fail("REJECTED needs from to sec nsec chi2 x y z qx qy qz qw and 21 information entries");
  for (int i = 0; i < 6; ++i)
    for (int j = i; j < 6; ++j) {
      if (!(in >> r.constraint.information(i, j)))
        where.fail("REJECTED needs 21 information entries");
      r.constraint.information(j, i) = r.constraint.information(i, j);
    }
  if (sec < 0 || nsec < 0 || nsec >= 1000000000LL || sec > 0xffffffffLL)
    where.fail("stamp out of range");
  r.stamp = ros::Time(static_cast<uint32_t>(sec), static_cast<uint32_t>(nsec));
  r.constraint.measurement = toro::Pose3(toro::Quaternion(qw, qx, qy, qz), toro::Vector3(x, y, z));
  if (!r.constraint.measurement.isFinite() || !r.constraint.information.allFinite() || !std::isfinite(r.chi2))
    where.fail("REJECTED values are not finite");
  return r;
}

}  // namespace

Sidecar readSidecar(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw toro::ParseError(path, 0, std::string("cannot open: ") + std::strerror(errno));
  return readSidecar(in, path);
}

namespace {

std::string readWhole(const GraphFileRef& file) {
  const FileDescriptor fd = openForReading(file);
  std::string text;
  char buffer[1 << 14];
  for (;;) {
    const ssize_t n = ::read(fd.get(), buffer, sizeof buffer);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) throw toro::ParseError(file.displayPath(), 0, std::string("read error: ") + std::strerror(errno));
    if (n == 0) return text;
    text.append(buffer, static_cast<std::size_t>(n));
  }
}

}  // namespace

Sidecar readSidecarFile(const GraphFileRef& file) {
  // A sidecar is small (about 100 bytes a keyframe): read whole.
  std::istringstream in(readWhole(file));
  return readSidecar(in, file.displayPath());
}

Sidecar readSidecar(std::istream& in, const std::string& source) {
  Sidecar out;
  std::string line;
  for (std::size_t n = 1; std::getline(in, line); ++n) {
    if (line.empty() || line[0] == '#') continue;
    const Where where{source, n};
    std::istringstream ls(line);
    std::string tag;
    ls >> tag;
    if (tag == "KEYFRAME") {
      out.keyframes.push_back(parseKeyframe(ls, where));
      if (out.keyframes.size() > 1 && out.keyframes[out.keyframes.size() - 2].id >= out.keyframes.back().id)
        where.fail("keyframe ids must increase");
    } else if (tag == "LOOP_CLOSURE") {
      long long c = -1;
      if (!(ls >> c) || c < 0) where.fail("LOOP_CLOSURE needs a constraint index >= 0");
      out.loop_closures.push_back(static_cast<std::size_t>(c));
    } else if (tag == "REJECTED") {
      out.rejected.push_back(parseRejected(ls, where));
    } else {
      constexpr const char* kExpected = " (expected KEYFRAME, LOOP_CLOSURE or REJECTED)";
      where.fail("unknown tag " + toro::excerpt(tag) + kExpected, std::string("unknown tag") + kExpected);
    }
  }
  return out;
}

namespace {

// Empty if nothing is at `file` or a regular file that `read` accepts; else why not.
std::string checkOne(const GraphFileRef& file, const char* kind, const std::function<void()>& read) {
  struct stat st;
  if (::fstatat(file.directoryFd(), file.name().c_str(), &st, AT_SYMLINK_NOFOLLOW) != 0)
    return errno == ENOENT ? "" : file.displayPath() + ": cannot check it: " + std::strerror(errno);
  if (S_ISLNK(st.st_mode)) return file.displayPath() + " is a symbolic link (a save would replace the link)";
  if (!S_ISREG(st.st_mode)) return file.displayPath() + " is not a regular file";
  try {
    read();
  } catch (const toro::ParseError& e) {
    return file.displayPath() + " is not " + kind + " (" + file.describe(e) + ")";
  }
  return "";
}

}  // namespace

std::string checkReplaceable(const GraphFileRef& graph) {
  const GraphFileRef sidecar = graph.sidecar();
  const std::string g = checkOne(graph, "a graph file", [&] {
    // The reader skips unknown tags (other tools' records), so any text whose lines start with a
    // word reads; a graph has a VERTEX or EDGE line, or nothing at all (an empty file).
    toro::ReadReport report;
    readGraphFile(graph, {}, &report);
    if (report.vertices + report.edges == 0 && (report.comment_lines > 0 || !report.skipped_tags.empty()))
      throw toro::ParseError(graph.displayPath(), 0, "no VERTEX or EDGE line");
  });
  if (!g.empty()) return g;
  return checkOne(sidecar, "a keyframe sidecar", [&] {
    // Ours start with the header writeSidecar writes (a file of comments alone would read too).
    const std::string text = readWhole(sidecar);
    if (!text.empty() && text.rfind(kSidecarHeader, 0) != 0)
      throw toro::ParseError(sidecar.displayPath(), 1, std::string("no '") + kSidecarHeader + "' header");
    std::istringstream in(text);
    readSidecar(in, sidecar.displayPath());
  });
}

}  // namespace toro_ros
