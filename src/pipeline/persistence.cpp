#include "toro_ros/pipeline/persistence.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iomanip>
#include <sstream>
#include <stdexcept>

namespace toro_ros {

std::string sidecarPath(const std::string& graph_path) { return graph_path + ".stamps"; }

std::string temporaryPath(const std::string& path) {
  const std::size_t slash = path.find_last_of('/');
  const std::string dir = slash == std::string::npos ? "" : path.substr(0, slash + 1);
  const std::string name = path.substr(dir.size());
  const std::size_t dot = name.find_last_of('.');
  const std::string stem = dot == std::string::npos || dot == 0 ? name : name.substr(0, dot);
  const std::string ext = dot == std::string::npos || dot == 0 ? "" : name.substr(dot);
  return dir + "." + stem + ".tmp" + std::to_string(::getpid()) + ext;
}

namespace {

void syncPath(const std::string& path, int flags) {
  const int fd = ::open(path.c_str(), flags);
  if (fd < 0) throw std::runtime_error(path + ": cannot open to sync: " + std::strerror(errno));
  const bool ok = ::fsync(fd) == 0;
  const int err = errno;
  ::close(fd);
  if (!ok) throw std::runtime_error(path + ": fsync failed: " + std::strerror(err));
}

}  // namespace

void commitFile(const std::string& temporary, const std::string& path) {
  syncPath(temporary, O_RDONLY);
  if (std::rename(temporary.c_str(), path.c_str()) != 0)
    throw std::runtime_error(path + ": cannot rename " + temporary + " to it: " + std::strerror(errno));
  const std::size_t slash = path.find_last_of('/');
  syncPath(slash == std::string::npos ? "." : (slash == 0 ? "/" : path.substr(0, slash)), O_RDONLY | O_DIRECTORY);
}

void writeSidecar(const std::string& path, const Sidecar& sidecar) {
  std::ofstream out(path);
  if (!out) throw std::runtime_error(path + ": cannot open for writing");
  out << "# toro_ros keyframe sidecar v1\n# KEYFRAME id sec nsec x y z qx qy qz qw (odom_T_base)\n"
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
  if (!out) throw std::runtime_error(path + ": write failed");
}

namespace {

KeyframeRecord parseKeyframe(std::istringstream& in, const std::string& where) {
  KeyframeRecord k;
  long long sec = 0, nsec = 0;
  double x, y, z, qx, qy, qz, qw;
  if (!(in >> k.id >> sec >> nsec >> x >> y >> z >> qx >> qy >> qz >> qw))
    throw std::runtime_error(where + "KEYFRAME needs id sec nsec x y z qx qy qz qw");
  if (sec < 0 || nsec < 0 || nsec >= 1000000000LL || sec > 0xffffffffLL)
    throw std::runtime_error(where + "stamp out of range");
  k.stamp = ros::Time(static_cast<uint32_t>(sec), static_cast<uint32_t>(nsec));
  k.odom_T_base = toro::Pose3(toro::Quaternion(qw, qx, qy, qz), toro::Vector3(x, y, z));
  if (!k.odom_T_base.isFinite()) throw std::runtime_error(where + "pose is not finite");
  return k;
}

RejectedLoopClosure parseRejected(std::istringstream& in, const std::string& where) {
  RejectedLoopClosure r;
  long long sec = 0, nsec = 0;
  double x, y, z, qx, qy, qz, qw;
  if (!(in >> r.constraint.from >> r.constraint.to >> sec >> nsec >> r.chi2 >> x >> y >> z >> qx >> qy >> qz >> qw))
    throw std::runtime_error(where + "REJECTED needs from to sec nsec chi2 x y z qx qy qz qw and 21 information entries");
  for (int i = 0; i < 6; ++i)
    for (int j = i; j < 6; ++j) {
      if (!(in >> r.constraint.information(i, j)))
        throw std::runtime_error(where + "REJECTED needs 21 information entries");
      r.constraint.information(j, i) = r.constraint.information(i, j);
    }
  if (sec < 0 || nsec < 0 || nsec >= 1000000000LL || sec > 0xffffffffLL)
    throw std::runtime_error(where + "stamp out of range");
  r.stamp = ros::Time(static_cast<uint32_t>(sec), static_cast<uint32_t>(nsec));
  r.constraint.measurement = toro::Pose3(toro::Quaternion(qw, qx, qy, qz), toro::Vector3(x, y, z));
  if (!r.constraint.measurement.isFinite() || !r.constraint.information.allFinite() || !std::isfinite(r.chi2))
    throw std::runtime_error(where + "REJECTED values are not finite");
  return r;
}

}  // namespace

Sidecar readSidecar(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error(path + ": cannot open");
  Sidecar out;
  std::string line;
  for (std::size_t n = 1; std::getline(in, line); ++n) {
    if (line.empty() || line[0] == '#') continue;
    const std::string where = path + ":" + std::to_string(n) + ": ";
    std::istringstream ls(line);
    std::string tag;
    ls >> tag;
    if (tag == "KEYFRAME") {
      out.keyframes.push_back(parseKeyframe(ls, where));
      if (out.keyframes.size() > 1 && out.keyframes[out.keyframes.size() - 2].id >= out.keyframes.back().id)
        throw std::runtime_error(where + "keyframe ids must increase");
    } else if (tag == "LOOP_CLOSURE") {
      long long c = -1;
      if (!(ls >> c) || c < 0) throw std::runtime_error(where + "LOOP_CLOSURE needs a constraint index >= 0");
      out.loop_closures.push_back(static_cast<std::size_t>(c));
    } else if (tag == "REJECTED") {
      out.rejected.push_back(parseRejected(ls, where));
    } else {
      throw std::runtime_error(where + "unknown tag '" + tag + "'");
    }
  }
  return out;
}

}  // namespace toro_ros
