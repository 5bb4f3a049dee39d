#include "toro_ros/offline/sample_graph.h"

#include <cmath>
#include <iostream>

#include "toro_ros/core/graph_io.h"
#include "toro_ros/offline/apps.h"
#include "toro_ros/offline/cli.h"

namespace toro_ros {
namespace offline {

double RoundedRectangle::perimeter() const {
  return 2 * (length - 2 * corner_radius) + 2 * (width - 2 * corner_radius) + 2 * M_PI * corner_radius;
}

toro::Vector3 RoundedRectangle::pointAt(double s) const {
  const double a = length - 2 * corner_radius, b = width - 2 * corner_radius, q = M_PI * corner_radius / 2;
  s = std::fmod(s, perimeter());
  if (s < 0) s += perimeter();
  // Segments: bottom (right half), corner, right side, corner, top, corner, left side, corner, bottom (left
  // half).
  const double segments[] = {a / 2, q, b, q, a, q, b, q, a / 2};
  const toro::Vector3 corners[] = {
      {a / 2, b / 2, 0}, {-a / 2, b / 2, 0}, {-a / 2, -b / 2, 0}, {a / 2, -b / 2, 0}};
  double x = 0, y = -width / 2;
  int i = 0;
  for (; i < 8 && s > segments[i]; s -= segments[i], ++i) {
  }
  switch (i) {
    case 0:
      x = s;
      break;
    case 2:
      x = length / 2, y = -b / 2 + s;
      break;
    case 4:
      x = a / 2 - s, y = width / 2;
      break;
    case 6:
      x = -length / 2, y = b / 2 - s;
      break;
    case 8:
      x = -a / 2 + s;
      break;
    default: {  // corners 1, 3, 5, 7: quarter circles
      const int c = (i - 1) / 2;
      const toro::Vector3 centre = c == 0   ? corners[3]
                                   : c == 1 ? corners[0]
                                   : c == 2 ? corners[1]
                                            : corners[2];
      const double angle = -M_PI / 2 + c * M_PI / 2 + s / corner_radius;
      x = centre.x() + corner_radius * std::cos(angle), y = centre.y() + corner_radius * std::sin(angle);
    }
  }
  return {x, y, 0.0};
}

namespace {

constexpr double kLength = 16.0, kWidth = 8.0, kCornerRadius = 2.0, kHill = 1.0;
constexpr int kPerLap = 48;

// The sample's path: the rounded rectangle over a hill centred at x = 0.
toro::Vector3 pointAt(double s) {
  const RoundedRectangle path{kLength, kWidth, kCornerRadius};
  const toro::Vector3 p = path.pointAt(s);
  const double z = kHill * 0.5 * (1 - std::cos(2 * M_PI * p.x() / kLength + M_PI));
  return {p.x(), p.y(), z};
}

double perimeter() { return RoundedRectangle{kLength, kWidth, kCornerRadius}.perimeter(); }

// A pose looking along the path (yaw and pitch from the tangent).
toro::Pose3 poseAt(double s) {
  const toro::Vector3 p = pointAt(s), d = (pointAt(s + 0.05) - pointAt(s - 0.05)).normalized();
  const double yaw = std::atan2(d.y(), d.x()), pitch = -std::asin(std::clamp(d.z(), -1.0, 1.0));
  return toro::Pose3::fromRollPitchYaw(p.x(), p.y(), p.z(), 0.0, pitch, yaw);
}

}  // namespace

toro::SyntheticGraph makeSampleGraph(const SampleOptions& options) {
  std::vector<toro::Pose3> truth;
  std::vector<std::pair<std::size_t, std::size_t>> closures;
  const double step = perimeter() / kPerLap;
  for (int i = 0; i < options.laps * kPerLap; ++i) {
    truth.push_back(poseAt(step * i));
    if (i >= kPerLap && i % options.closure_every == 0)
      closures.emplace_back(static_cast<std::size_t>(i - kPerLap), static_cast<std::size_t>(i));
  }
  return toro::makeFromTrajectory(truth, closures, options.noise);
}

int runMakeSampleGraph(int argc, char** argv) {
  const std::vector<ArgSpec> specs = {{"laps", "laps driven (>= 2). Default 3"},
                                      {"seed", "noise seed. Default 42"}};
  try {
    const ParsedArgs args = parseArgs(argc, argv, specs);
    if (args.help || args.positional.size() != 1) {
      std::cerr << usage("make_sample_graph OUTPUT.g2o [--laps N] [--seed S]", specs);
      return args.help ? 0 : 2;
    }
    SampleOptions o;
    o.laps = args.integer("laps", o.laps);
    o.noise.seed = static_cast<std::uint32_t>(args.integer("seed", static_cast<int>(o.noise.seed)));
    if (o.laps < 2) throw std::invalid_argument("--laps: must be >= 2 (loop closures join consecutive laps)");
    const toro::SyntheticGraph g = makeSampleGraph(o);
    toro::writeGraph(g.graph, args.positional[0]);
    std::cout << "wrote " << args.positional[0] << ": " << g.graph.numNodes()
              << " poses (vertices = ground truth), " << g.graph.numConstraints() << " constraints\n";
    return 0;
  } catch (const std::invalid_argument& e) {
    std::cerr << "make_sample_graph: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "make_sample_graph: " << e.what() << "\n";
    return 1;
  }
}

}  // namespace offline
}  // namespace toro_ros
