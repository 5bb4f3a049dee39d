#include "toro_ros/pipeline/persistence.h"

#include <fstream>
#include <iomanip>
#include <sstream>
#include <stdexcept>

namespace toro_ros {

std::string sidecarPath(const std::string& graph_path) { return graph_path + ".stamps"; }

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
    } else {
      throw std::runtime_error(where + "unknown tag '" + tag + "'");
    }
  }
  return out;
}

}  // namespace toro_ros
