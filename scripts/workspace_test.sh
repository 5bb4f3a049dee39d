#!/usr/bin/env bash
# The catkin workspace route, as ROS users build the package (README.md, "Requirements"), in a
# fresh workspace under a temporary directory with nothing beside the package (no ../shared):
#   mkdir -p ws/src && cp -r <repo> ws/src/toro_ros && cd ws && catkin_make &&
#   catkin_make run_tests && catkin_test_results build/test_results && catkin_make install
# then checks the install space (the package, the node, the nodelet plugin are found there).
#
# What it runs of run_tests: by default (TORO_WORKSPACE_TESTS=workspace) the tests whose outcome
# depends on the workspace rather than on the code, which the normal build's ctest proves
# already: every rostest (the environment catkin cached at the first configure: package path,
# Python path of the generated messages, libraries, the nodelet plugin), the launch-file test,
# and the tests of the shared datasets (they must skip without them).  TORO_WORKSPACE_TESTS=all
# runs the whole `catkin_make run_tests`.  Cost: bench/ci_timing.md.
#
# Environment: TORO_JOBS (default 2), TORO_WORKSPACE_DIR (default: a new temporary directory,
# removed afterwards unless TORO_KEEP_WORKSPACE=1).
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
JOBS="${TORO_JOBS:-2}"
TESTS="${TORO_WORKSPACE_TESTS:-workspace}"
export PYENV_VERSION=system ROS_HOSTNAME=localhost
# A shell that sourced some devel/setup.bash would leak its paths into the new workspace's cache.
unset CMAKE_PREFIX_PATH LD_LIBRARY_PATH PKG_CONFIG_PATH PYTHONPATH ROS_PACKAGE_PATH _CATKIN_SETUP_DIR \
  ROS_DISTRO ROS_ETC_DIR ROS_MASTER_URI ROS_PYTHON_VERSION ROS_VERSION

WS="${TORO_WORKSPACE_DIR:-$(mktemp -d "${TMPDIR:-/tmp}/toro_ws_XXXXXX")}"
cleanup() { [[ "${TORO_KEEP_WORKSPACE:-0}" == 1 ]] || rm -rf "${WS}"; }
trap cleanup EXIT

step() {
  local name="$1" start
  shift
  start=$(date +%s)
  echo "workspace_test.sh: ${name}"
  "$@" </dev/null
  echo "workspace_test.sh: ${name}: $(($(date +%s) - start)) s"
}

# The package as a clone has it: tracked files and new ones not ignored (no build directories).
copyPackage() {
  mkdir -p "${WS}/src/toro_ros"
  git -C "${REPO_ROOT}" ls-files -z --cached --others --exclude-standard |
    (cd "${REPO_ROOT}" && xargs -0 -r sh -c 'for f; do [ -e "$f" ] && printf "%s\0" "$f"; done' _) |
    tar -C "${REPO_ROOT}" --null -T - -cf - | tar -C "${WS}/src/toro_ros" -xf -
}

runTests() {
  if [[ "${TESTS}" == all ]]; then
    catkin_make -j"${JOBS}" run_tests
  else
    catkin_make -j"${JOBS}" run_tests_toro_ros_rostest run_tests_toro_ros_launch \
      run_tests_toro_ros_gtest_test_loop_closure_gate run_tests_toro_ros_gtest_test_graph_io_datasets
  fi
}

# catkin_test_results fails on failures and errors; also insist that the tests ran at all.
checkResults() {
  catkin_test_results build/test_results
  local rostests launch
  rostests=$(find build/test_results/toro_ros -name 'rostest-*.xml' | wc -l)
  launch=$(find build/test_results/toro_ros -name 'rosunit-test_launch_files.xml' | wc -l)
  if [[ "${rostests}" -lt 7 || "${launch}" -ne 1 ]]; then
    echo "workspace_test.sh: expected 7 rostest results and the launch-file test, found ${rostests} and ${launch}" >&2
    return 1
  fi
  grep -q 'skipped="2"' build/test_results/toro_ros/gtest-test_loop_closure_gate.xml ||
    { echo "workspace_test.sh: test_loop_closure_gate did not skip without the datasets" >&2; return 1; }
}

# The install space alone (no devel, no source) finds the package, its node and its nodelet.
checkInstall() {
  (
    unset ROS_PACKAGE_PATH CMAKE_PREFIX_PATH LD_LIBRARY_PATH PYTHONPATH
    # catkin's setup files (and Debian's ROS hooks they run) use unset variables.
    set +u
    # shellcheck disable=SC1091
    source install/setup.bash
    set -u
    local share
    share="$(rospack find toro_ros)"
    [[ "${share}" == "${WS}/install/share/toro_ros" ]] || { echo "rospack find toro_ros: ${share}" >&2; exit 1; }
    for f in lib/toro_ros/map_corrector_node lib/libtoro_ros_nodelet.so lib/toro_ros/replay_finish.py \
      share/toro_ros/launch/map_corrector.launch share/toro_ros/config/map_corrector.yaml \
      share/toro_ros/rviz/map_corrector.rviz include/toro_ros/MapCorrectorConfig.h \
      lib/python3/dist-packages/toro_ros/msg/_PoseGraph.py lib/python3/dist-packages/toro_ros/cfg/MapCorrectorConfig.py; do
      [[ -e "install/${f}" ]] || { echo "not installed: ${f}" >&2; exit 1; }
    done
    rospack plugins --attrib=plugin nodelet | grep -q "^toro_ros ${WS}/install/share/toro_ros/nodelet_plugins.xml" ||
      { echo "the nodelet plugin is not exported from the install space" >&2; exit 1; }
  )
}

main() {
  echo "workspace_test.sh: fresh workspace ${WS} (tests: ${TESTS}, -j${JOBS})"
  copyPackage
  cd "${WS}"
  [[ ! -e "${WS}/src/shared" ]] || { echo "workspace_test.sh: ${WS}/src/shared exists; the workspace must be fresh" >&2; exit 1; }
  step "catkin_make" catkin_make -j"${JOBS}"
  step "catkin_make run_tests (${TESTS})" runTests
  step "catkin_test_results" checkResults
  step "catkin_make install" catkin_make -j"${JOBS}" install
  step "install space" checkInstall
}

main "$@"
