#!/usr/bin/env bash
# Configures and builds toro_ros (libraries, tools, benchmarks and tests) into ${TORO_BUILD_DIR:-build}.
#
# Environment: TORO_BUILD_DIR (build directory, relative to the repo root or absolute; default build),
# TORO_JOBS (parallel jobs, default 2), TORO_BUILD_TYPE (default Release),
# TORO_BUILD_TARGETS (space-separated, default "all tests benchmarks"; e.g. "bench_toro" for one benchmark),
# TORO_SKIP_INSTALL=1 (do not run scripts/install_deps.sh first).
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${TORO_BUILD_DIR:-build}"
[[ "${BUILD_DIR}" = /* ]] || BUILD_DIR="${REPO_ROOT}/${BUILD_DIR}"
JOBS="${TORO_JOBS:-2}"
BUILD_TYPE="${TORO_BUILD_TYPE:-Release}"
read -r -a TARGETS <<<"${TORO_BUILD_TARGETS:-all tests benchmarks}"

# A pyenv python3 first on PATH cannot import the ROS Python modules; use Debian's.
export PYENV_VERSION=system
export ROS_HOSTNAME=localhost
PYTHON=/usr/bin/python3

# Drops the entries of a ':'-separated list that lie in a catkin devel space or are the repo itself.
withoutDevelEntries() {
  local list="$1" entry out=""
  local -a entries
  IFS=':' read -r -a entries <<<"${list}"
  for entry in "${entries[@]}"; do
    [[ -z "${entry}" ]] && continue
    [[ "${entry}" == */devel || "${entry}" == */devel/* ]] && continue
    [[ "${entry%/}" == "${REPO_ROOT}" ]] && continue
    out="${out:+${out}:}${entry}"
  done
  printf '%s' "${out}"
}

# Configuring from a shell that sourced <build>/devel/setup.bash leaves catkin's cached environment
# empty (later: ResourceNotFound in tests), so remove what that setup file adds.
cleanDevelEnvironment() {
  local var value
  for var in CMAKE_PREFIX_PATH LD_LIBRARY_PATH PKG_CONFIG_PATH PYTHONPATH ROS_PACKAGE_PATH; do
    if [[ -n "${!var+set}" ]]; then
      value="$(withoutDevelEntries "${!var}")"
      if [[ -n "${value}" ]]; then export "${var}=${value}"; else unset "${var}"; fi
    fi
  done
  # Set by the same setup file (Debian's ros-environment hooks); when already present catkin leaves
  # them out of its cached environment, so the test environment would lack them.
  unset _CATKIN_SETUP_DIR ROS_DISTRO ROS_ETC_DIR ROS_MASTER_URI ROS_PYTHON_VERSION ROS_VERSION
}

configure() {
  cmake -S "${REPO_ROOT}" -B "${BUILD_DIR}" -DCMAKE_BUILD_TYPE="${BUILD_TYPE}" \
    -DPYTHON_EXECUTABLE="${PYTHON}" -DPython3_EXECUTABLE="${PYTHON}" </dev/null
}

main() {
  # On a fresh machine CMake would stop at "could not find catkin"; install what is missing first,
  # as demo.sh and test.sh do (quick when everything is there).  TORO_SKIP_INSTALL=1 skips it.
  if [[ "${TORO_SKIP_INSTALL:-0}" != 1 ]]; then
    bash "${REPO_ROOT}/scripts/install_deps.sh" </dev/null
  fi
  cleanDevelEnvironment
  echo "build.sh: configuring ${REPO_ROOT} into ${BUILD_DIR} (${BUILD_TYPE})"
  configure
  echo "build.sh: building ${TARGETS[*]} with -j${JOBS}"
  # Test executables are not part of `all` in catkin; `tests` builds them.
  # (The cached test environment is right from the first configure: CMakeLists.txt creates the
  # devel folders it must list before catkin takes its snapshot.)
  cmake --build "${BUILD_DIR}" -j"${JOBS}" --target "${TARGETS[@]}" </dev/null
}

main "$@"
