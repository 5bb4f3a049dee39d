#!/usr/bin/env bash
# The README's main command: installs what is missing, builds, then
#   1. replays the bundled sample bag (made at build time by graph_to_bag: a synthetic robot with
#      drifting odometry, 32 loop closures, truth known) with `rosbag play --clock` through
#      map_corrector_node (launch/replay.launch, headless), printing the error before and after;
#   2. runs the same bag through toro_offline and draws the pictures (out/offline/trajectory.png and,
#      unless TORO_DEMO_RVIZ=0, a headless rviz screenshot out/rviz_replay.png);
#   3. optimises the bundled dataset test/data/smallGrid3D.g2o with toro_optimize (TORO only, and the
#      default TORO + sparse finish), and parking-garage.g2o too if ../shared/datasets exists.
# Results (graphs, reports, pictures, logs) go to out/ (git-ignored).
#
# Environment: TORO_BUILD_DIR (default build), TORO_DEMO_ITERATIONS (TORO-only iterations, default 100),
# TORO_DEMO_RVIZ (default 1; 0 skips the rviz screenshot).
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${TORO_BUILD_DIR:-build}"
[[ "${BUILD_DIR}" = /* ]] || BUILD_DIR="${REPO_ROOT}/${BUILD_DIR}"
ITERATIONS="${TORO_DEMO_ITERATIONS:-100}"
OUT_DIR="${REPO_ROOT}/out"
OPTIMIZE="${BUILD_DIR}/devel/lib/toro_ros/toro_optimize"

bash "${REPO_ROOT}/scripts/install_deps.sh" </dev/null
TORO_BUILD_TARGETS="${TORO_BUILD_TARGETS:-all}" bash "${REPO_ROOT}/scripts/build.sh" </dev/null

# Optimises one file in one mode; the summary of toro_optimize -q is the before/after report.
optimiseFile() {
  local input="$1" tag="$2" title="$3" name
  shift 3
  name="$(basename "${input%.*}")_${tag}"
  echo
  echo "=== $(basename "${input}"): ${title} ==="
  "${OPTIMIZE}" -q "$@" -o "${OUT_DIR}/${name}.g2o" "${input}" </dev/null | tee "${OUT_DIR}/${name}_report.txt"
  echo "optimised graph: out/${name}.g2o, report: out/${name}_report.txt"
}

# TORO alone (the paper's method), then toro_optimize's default: TORO until its progress slows,
# then the sparse Levenberg-Marquardt finish on the g2o chi2.
optimiseBothWays() {
  optimiseFile "$1" toro "TORO 3D only, ${ITERATIONS} iterations" --mode toro -i "${ITERATIONS}"
  optimiseFile "$1" toro_finish "default mode: TORO, then the sparse Levenberg-Marquardt finish"
}

# ---------------------------------------------------------------------------------------------
# The main job: the bundled sample bag (made at build time by graph_to_bag from a synthetic robot
# driving three laps with drifting odometry and 32 loop closures, truth known exactly) replayed with
# `rosbag play --clock` through map_corrector_node (headless), then the same bag through
# toro_offline, the pictures, and an rviz screenshot.
# ---------------------------------------------------------------------------------------------
SAMPLE_BAG="${BUILD_DIR}/sample/sample.bag"
replayDemo() {
  local port log
  port=$((11500 + RANDOM % 400))
  log="${OUT_DIR}/replay/launch.log"
  mkdir -p "${OUT_DIR}/replay"
  echo
  echo "=== replay: rosbag play --clock ${SAMPLE_BAG#"${REPO_ROOT}"/} through map_corrector_node (2x speed) ==="
  (
    set +u  # the ROS setup files read unset variables
    # shellcheck disable=SC1091
    source "${BUILD_DIR}/devel/setup.bash"
    export PYENV_VERSION=system ROS_HOSTNAME=localhost ROS_MASTER_URI="http://localhost:${port}"
    timeout 300 roslaunch -p "${port}" toro_ros replay.launch bag:="${SAMPLE_BAG}" rate:=2 \
      config:="${REPO_ROOT}/config/replay_sample.yaml" output_dir:="${OUT_DIR}/replay" </dev/null >"${log}" 2>&1
  ) || true
  if ! grep -q "^replay_finish: corrected graph written" "${log}"; then
    echo "the replay did not finish; its log: ${log}" >&2
    tail -20 "${log}" >&2
    return 1
  fi
  grep -E "replay_finish: (bag played|~optimize)" "${log}" | sed 's/^.*replay_finish: /  /'
  sed -n '/^replay_finish: corrected graph written/,/^replay_finish: final corrected pose/p' "${log}" | sed 's/^replay_finish: //'
  echo "full log: out/replay/launch.log"
}

offlineDemo() {
  echo
  echo "=== offline: toro_offline on the same bag (no master, full speed), then the pictures ==="
  "${BUILD_DIR}/devel/lib/toro_ros/toro_offline" "${SAMPLE_BAG}" --config "${REPO_ROOT}/config/replay_sample.yaml" \
    --output-dir "${OUT_DIR}/offline" </dev/null
  /usr/bin/python3 "${REPO_ROOT}/scripts/plot_trajectory.py" "${OUT_DIR}/offline/summary.json" \
    -o "${OUT_DIR}/offline/trajectory.png"
  if [[ "${TORO_DEMO_RVIZ:-1}" != 0 ]]; then
    BUILD_DIR="${BUILD_DIR}" bash "${REPO_ROOT}/scripts/rviz_screenshot.sh" "${SAMPLE_BAG}" "${OUT_DIR}/rviz_replay.png" \
      </dev/null | tail -1 || echo "(rviz screenshot failed; TORO_DEMO_RVIZ=0 skips it)"
  fi
}

mkdir -p "${OUT_DIR}"
replayDemo
offlineDemo

echo
echo "Error measures (../shared/datasets/REFERENCE.md; compare each only with itself): g2o chi2, the"
echo "SE-Sync objective, and TORO's unweighted error (sum of squared rotation angles and translations)."
optimiseBothWays "${REPO_ROOT}/test/data/smallGrid3D.g2o"
echo "(smallGrid3D: best known g2o chi2 458.154, SE-Sync optimum 1025.40; see test/data/README.md)"
SHARED_GARAGE="$(cd "${REPO_ROOT}/.." && pwd)/shared/datasets/parking-garage.g2o"
if [[ -f "${SHARED_GARAGE}" ]]; then
  optimiseBothWays "${SHARED_GARAGE}"
  echo "(parking-garage: best known g2o chi2 1.23869, SE-Sync optimum 1.26252)"
fi
