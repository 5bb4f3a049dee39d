#!/usr/bin/env bash
# The README's main command (for now): installs what is missing, builds, then optimises the bundled
# dataset test/data/smallGrid3D.g2o with toro_optimize (TORO only, and the default TORO + sparse
# finish) and prints the error before and after.  If
# the shared dataset folder sits beside the repo (../shared/datasets), parking-garage.g2o is
# optimised too.  Results (optimised graphs and the printed reports) go to out/ (git-ignored).
#
# Environment: TORO_BUILD_DIR (default build), TORO_DEMO_ITERATIONS (TORO-only iterations, default 100).
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

mkdir -p "${OUT_DIR}"
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
