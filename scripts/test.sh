#!/usr/bin/env bash
# The README's test command (and CI's, through .ci/run): installs what is missing, builds
# everything, runs every test.  Stages, in order:
#   1. the normal build (scripts/build.sh);
#   2. the catkin workspace stage (scripts/workspace_test.sh): catkin_make, catkin_make run_tests
#      (the tests that depend on the workspace: rostests, launch files, dataset skips),
#      catkin_test_results and catkin_make install in a fresh workspace under a temporary directory;
#   3. the sanitizer stages (scripts/sanitize.sh all): the whole test suite in an ASan+UBSan build,
#      the worker thread tests in a TSan build; any failing test or sanitizer report fails it;
#   4. the fuzz stage (scripts/fuzz.sh): every libFuzzer target for TORO_TEST_FUZZ_SEC seconds;
#   5. ctest of the normal build, the LAST runner: when everything before passed, the script's exit
#      code is ctest's and its closing line ("100% tests passed, 0 tests failed out of N") is the
#      verdict.  A failing stage 2, 3 or 4 stops the script there with "test.sh: ... FAILED" and a
#      non-zero exit code.
# The extra stages are on by default; developers iterating on a change may turn them off:
#   TORO_TEST_WORKSPACE=0    skip stage 2;      TORO_TEST_SANITIZERS=0   skip stage 3
#   TORO_TEST_FUZZ_SEC=0     skip stage 4;      TORO_TEST_FUZZ_SEC=N     N seconds per fuzz target (default 20)
# Cost on the 2-core CI machine: bench/ci_timing.md.
# Environment also: TORO_BUILD_DIR (default build), TORO_JOBS (default 2); see scripts/build.sh,
# scripts/sanitize.sh (TORO_ASAN_BUILD_DIR, TORO_TSAN_BUILD_DIR) and scripts/fuzz.sh.
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${TORO_BUILD_DIR:-build}"
[[ "${BUILD_DIR}" = /* ]] || BUILD_DIR="${REPO_ROOT}/${BUILD_DIR}"
WORKSPACE="${TORO_TEST_WORKSPACE:-1}"
SANITIZERS="${TORO_TEST_SANITIZERS:-1}"
FUZZ_SEC="${TORO_TEST_FUZZ_SEC:-20}"

# stage <name> <command...>: runs one stage, prints its time, stops the script if it fails.
stage() {
  local name="$1" start rc=0
  shift
  start=$(date +%s)
  echo "test.sh: === ${name} ==="
  "$@" </dev/null || rc=$?
  if [[ ${rc} -ne 0 ]]; then
    echo "test.sh: ${name} FAILED (exit code ${rc}, after $(($(date +%s) - start)) s); see above." >&2
    echo "test.sh: the normal build's ctest was not run." >&2
    exit "${rc}"
  fi
  echo "test.sh: ${name} passed in $(($(date +%s) - start)) s"
}

stage "install_deps" bash "${REPO_ROOT}/scripts/install_deps.sh"
stage "normal build" bash "${REPO_ROOT}/scripts/build.sh"
if [[ "${WORKSPACE}" != 0 ]]; then
  stage "catkin workspace stage (fresh workspace: catkin_make, run_tests, install)" \
    bash "${REPO_ROOT}/scripts/workspace_test.sh"
else
  echo "test.sh: catkin workspace stage skipped (TORO_TEST_WORKSPACE=0)"
fi
if [[ "${SANITIZERS}" != 0 ]]; then
  stage "sanitizer stages (ASan+UBSan: whole suite; TSan: worker thread tests)" \
    bash "${REPO_ROOT}/scripts/sanitize.sh" all
else
  echo "test.sh: sanitizer stages skipped (TORO_TEST_SANITIZERS=0)"
fi
if [[ "${FUZZ_SEC}" != 0 ]]; then
  stage "fuzz stage (${FUZZ_SEC} s per target)" bash "${REPO_ROOT}/scripts/fuzz.sh" "${FUZZ_SEC}"
else
  echo "test.sh: fuzz stage skipped (TORO_TEST_FUZZ_SEC=0)"
fi

# rostests run Python entry points: Debian's python3, and a master that needs no DNS.
export PYENV_VERSION=system ROS_HOSTNAME=localhost
cd "${BUILD_DIR}"
echo "test.sh: === ctest of the normal build ==="
exec ctest --output-on-failure </dev/null
