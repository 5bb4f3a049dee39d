#!/usr/bin/env bash
# Installs the Debian 12 packages needed to build, test, run and plot toro_ros.
#
# Idempotent and quick when everything is present: each package is checked with dpkg-query first,
# and apt-get (update + install) runs only for what is missing.  Never reads stdin.
set -euo pipefail

# The one list of packages.  ROS 1 comes from Debian's own archive (see README.md).
# Later features add their packages here.
TORO_APT_PACKAGES=(
  # toolchain
  build-essential cmake g++ git
  # ROS 1 (Debian packages): build, messages, tf2, rosbag, rostest, command-line tools, rviz
  catkin libroscpp-dev ros-message-generation ros-message-runtime
  libstd-msgs-dev ros-std-msgs libgeometry-msgs-dev ros-geometry-msgs
  libnav-msgs-dev ros-nav-msgs libvisualization-msgs-dev ros-visualization-msgs
  libstd-srvs-dev ros-std-srvs libtf2-ros-dev libtf2-eigen-dev libtf2-geometry-msgs-dev
  libeigen3-dev librosbag-dev python3-rosbag librostest-dev python3-rostest libgtest-dev
  rosbash python3-roslaunch python3-rosnode python3-rostopic python3-rosservice python3-rospy
  python3-geometry-msgs python3-nav-msgs python3-visualization-msgs python3-std-srvs
  python3-tf2-ros python3-tf2-geometry-msgs tf2-tools rviz xvfb imagemagick
  libdiagnostic-updater-dev
  # run-time tuning (dynamic_reconfigure: C++ server/client, and the Python generator of
  # cfg/MapCorrector.cfg) and the nodelet (library, and the nodelet manager binary)
  libdynamic-reconfigure-config-init-mutex-dev python3-dynamic-reconfigure
  libnodeletlib-dev libnodelet-dev libnodeletlib-tools
  # maths, benchmarks, plots
  libsuitesparse-dev libbenchmark-dev python3-matplotlib python3-numpy
  # an optimised BLAS for CHOLMOD's supernodal factorisation (3-4x faster than the reference BLAS
  # that libsuitesparse-dev pulls in; bench/finish_results.md)
  libopenblas0-pthread
  # fuzzing (scripts/fuzz.sh): clang and its libFuzzer/sanitizer runtimes (only recommended by clang)
  clang libclang-rt-14-dev
)

missingPackages() {
  local pkg status
  for pkg in "${TORO_APT_PACKAGES[@]}"; do
    status=$(dpkg-query -W -f='${db:Status-Status}' "${pkg}" 2>/dev/null || true)
    if [[ "${status}" != "installed" ]]; then
      echo "${pkg}"
    fi
  done
}

main() {
  if ! command -v dpkg-query >/dev/null 2>&1 || ! command -v apt-get >/dev/null 2>&1; then
    echo "install_deps.sh: this script needs a Debian 12 (apt/dpkg) system." >&2
    exit 1
  fi

  local missing
  mapfile -t missing < <(missingPackages)
  if [[ ${#missing[@]} -eq 0 ]]; then
    echo "install_deps.sh: all ${#TORO_APT_PACKAGES[@]} required packages are installed."
    return 0
  fi
  echo "install_deps.sh: installing ${#missing[@]} missing package(s): ${missing[*]}"

  local -a sudo_cmd=()
  if [[ "$(id -u)" -ne 0 ]]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
      sudo_cmd=(sudo -n)
    elif command -v sudo >/dev/null 2>&1 && [[ -t 1 ]] && [[ -r /dev/tty ]]; then
      # Interactive terminal: sudo asks for the password on /dev/tty (stdin is never read).
      sudo_cmd=(sudo)
    else
      echo "install_deps.sh: not root and passwordless sudo is not available." >&2
      echo "Install these packages as root, then run this script again:" >&2
      echo "  apt-get update && apt-get install -y --no-install-recommends ${missing[*]}" >&2
      exit 1
    fi
  fi

  export DEBIAN_FRONTEND=noninteractive
  "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update </dev/null
  "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive \
    apt-get install -y --no-install-recommends "${missing[@]}" </dev/null
}

main "$@"
