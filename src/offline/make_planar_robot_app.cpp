#include <iostream>

#include "toro_ros/offline/apps.h"
#include "toro_ros/offline/cli.h"
#include "toro_ros/offline/planar_robot.h"

namespace toro_ros {
namespace offline {

namespace {

const std::vector<ArgSpec> kSpecs = {
    {"style",
     "odometry covariance: constant (diff_drive_controller, 1e6 on z/roll/pitch), ekf_two_d "
     "(robot_localization two_d_mode, 1e-6 there), ekf_two_d_zero (0 there) or zero. Default constant"},
    {"laps", "laps of the 71.7 m loop (>= 2). Default 3"},
    {"seed", "noise seed. Default 1"},
    {"out-of-plane", "stddev of loop-closure noise on z (m), roll and pitch (rad). Default 0"},
    {"speed", "m/s. Default 1.0"},
    {"start", "stamp of the first message, s. Default 1000"},
};

}  // namespace

int runMakePlanarRobot(int argc, char** argv) {
  const std::string synopsis = "make_planar_robot OUTPUT.bag [options]";
  try {
    const ParsedArgs args = parseArgs(argc, argv, kSpecs);
    if (args.help || args.positional.size() != 1) {
      std::cerr << usage(synopsis, kSpecs);
      return args.help ? 0 : 2;
    }
    PlanarRobotOptions o;
    const std::string style = args.text("style", toString(o.covariance_style));
    const auto parsed = odometryCovarianceStyleFromString(style);
    if (!parsed)
      throw std::invalid_argument("--style: expected constant, ekf_two_d, ekf_two_d_zero or zero, got '" +
                                  style + "'");
    o.covariance_style = *parsed;
    o.laps = args.integer("laps", o.laps);
    o.seed = static_cast<std::uint32_t>(args.integer("seed", static_cast<int>(o.seed)));
    o.loop_closure_out_of_plane_stddev = args.number("out-of-plane", o.loop_closure_out_of_plane_stddev);
    o.speed_mps = args.number("speed", o.speed_mps);
    o.start_sec = args.number("start", o.start_sec);
    const std::string& bag = args.positional[0];
    if (bag.size() < 5 || bag.substr(bag.size() - 4) != ".bag")
      throw std::invalid_argument("output '" + bag + "': must end in .bag");
    const PlanarRobot robot = makePlanarRobot(o);
    const auto [largest, last] = odometryDrift(robot);
    std::cout << robot.odometry.size() << " odometry messages over " << robot.path_length_m << " m, "
              << robot.loop_closures.size() << " loop closures; odometry drift " << largest << " m at most, "
              << last << " m at the end; covariance style " << toString(o.covariance_style) << "\n";
    for (const std::string& f : writePlanarRobot(robot, bag)) std::cout << "wrote " << f << "\n";
    return 0;
  } catch (const std::invalid_argument& e) {
    std::cerr << "make_planar_robot: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "make_planar_robot: " << e.what() << "\n";
    return 1;
  }
}

}  // namespace offline
}  // namespace toro_ros
