#!/usr/bin/env bash
# Runs the tests under sanitizers (called by scripts/test.sh before the normal build's ctest):
#   address: the whole test suite in an ASan+UBSan build (TORO_ASAN_BUILD_DIR, default build-asan);
#   thread:  the tests that run threads (the node's rostest: its worker thread, timers and
#            callbacks) and the pipeline tests the worker runs in a TSan build (TORO_TSAN_BUILD_DIR, default build-tsan).
# A sanitizer report from any process (test, node, tool) is written under <build>/sanitizer-reports/;
# the script fails if a ctest fails or any report was written, and prints the reports.
#   scripts/sanitize.sh [address|thread|all]      (default all)
# Suppressions (third-party code only, one comment per entry): test/sanitizers/*.supp.
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WHICH="${1:-all}"
export PYENV_VERSION=system ROS_HOSTNAME=localhost

absolute() { [[ "$1" = /* ]] && printf '%s' "$1" || printf '%s/%s' "${REPO_ROOT}" "$1"; }

# configureAndBuild <build dir> <sanitizer> <targets>
configureAndBuild() {
  cmake -S "${REPO_ROOT}" -B "$1" -DTORO_SANITIZER="$2" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3 >/dev/null </dev/null
  TORO_BUILD_DIR="$1" TORO_BUILD_TYPE=RelWithDebInfo TORO_BUILD_TARGETS="$3" \
    bash "${REPO_ROOT}/scripts/build.sh" >"$1/sanitize-build.log" 2>&1 </dev/null ||
    { tail -n 40 "$1/sanitize-build.log" >&2; return 1; }
}

# checkReports <build dir> <name>: fails if any sanitizer report was written.
checkReports() {
  local reports=("$1"/sanitizer-reports/report.*)
  if [[ -e "${reports[0]}" ]]; then
    echo "sanitize.sh: $2 reported problems:" >&2
    head -n 60 "${reports[@]}" >&2
    return 1
  fi
  echo "sanitize.sh: $2: no sanitizer report"
}

runAddress() {
  local build
  build="$(absolute "${TORO_ASAN_BUILD_DIR:-build-asan}")"
  echo "sanitize.sh: ASan+UBSan build of everything in ${build}"
  configureAndBuild "${build}" address "all tests"
  rm -rf "${build}/sanitizer-reports" && mkdir -p "${build}/sanitizer-reports"
  local common="log_path=${build}/sanitizer-reports/report"
  (cd "${build}" &&
    ASAN_OPTIONS="${common}:detect_leaks=1:suppressions=${REPO_ROOT}/test/sanitizers/asan.supp" \
    LSAN_OPTIONS="suppressions=${REPO_ROOT}/test/sanitizers/lsan.supp" \
    UBSAN_OPTIONS="${common}:print_stacktrace=1:halt_on_error=1" \
    ctest --output-on-failure </dev/null)
  checkReports "${build}" "ASan+UBSan"
}

runThread() {
  local build
  build="$(absolute "${TORO_TSAN_BUILD_DIR:-build-tsan}")"
  echo "sanitize.sh: TSan build of the node and pipeline tests in ${build}"
  # Only what the selected tests need: TSan builds are slow and the rest runs no threads.
  configureAndBuild "${build}" thread \
    "toro_ros_generate_messages map_corrector_node map_corrector test_pipeline test_load test_bad_input"
  rm -rf "${build}/sanitizer-reports" && mkdir -p "${build}/sanitizer-reports"
  (cd "${build}" &&
    TSAN_OPTIONS="log_path=${build}/sanitizer-reports/report:second_deadlock_stack=1:suppressions=${REPO_ROOT}/test/sanitizers/tsan.supp" \
    ctest --output-on-failure -R 'rostest_test_node|test_pipeline$|test_load$|test_bad_input$' </dev/null)
  checkReports "${build}" "TSan"
}

case "${WHICH}" in
  address) runAddress ;;
  thread) runThread ;;
  all) runAddress && runThread ;;
  *) echo "usage: scripts/sanitize.sh [address|thread|all]" >&2; exit 2 ;;
esac
