#!/usr/bin/env bash
# Runs the tests under sanitizers (scripts/test.sh runs both stages before the normal build's ctest):
#   address: the whole test suite (every ctest test, rostests included) in an ASan+UBSan build
#            (TORO_ASAN_BUILD_DIR, default build-asan), except graph_topics_nodelet.test: its
#            nodelet manager is Debian's uninstrumented /usr/lib/nodelet/nodelet, which cannot load
#            an ASan library (the runtime must come first); the same MapCorrectorNode and client
#            run under ASan in graph_topics.test;
#   thread:  the worker thread tests in a TSan build (TORO_TSAN_BUILD_DIR, default build-tsan):
#            test_pipeline_worker (the node's worker thread without ROS transport: producers,
#            service commands and snapshot readers on other threads while it applies and optimises).
#            The node's rostest is not run under TSan: it is not clean there, for reasons outside
#            our code (measured; bench/ci_timing.md):
#            - node and client report ~2,500 lock-order inversions and ~40 data races whose frames
#              lie in roscpp and log4cxx (TransportTCP::read/write, Connection::addDropListener,
#              write, writeTransport and destructor, TopicManager::lookupPublication, PollManager):
#              these libraries are not instrumented, so TSan sees only the halves of their
#              synchronisation inlined into our code.  Silencing them would take whole-library
#              suppressions (libroscpp.so), which match every stack through roscpp's callback
#              threads and so would also hide races in our own callbacks: not honest;
#            - the client publishes its odometry in a paced burst and waits a fixed time for the
#              node to have counted all of it; the TSan-slowed node does not keep up and the
#              test times out (a timing assumption of the test, not a race).
#            What the node's threads do with our data is covered by test_pipeline_worker.
#            TORO_TSAN_ROSTEST=1 runs it anyway (adds the node and the client to the TSan build).
# A sanitizer report from any process (test, node, tool) is written under <build>/sanitizer-reports/;
# a stage fails if a ctest fails or any report was written, and prints the reports.
#   scripts/sanitize.sh [address|thread|all]      (default all)
# Suppressions (third-party code only, one comment per entry): test/sanitizers/*.supp.
#
# Cost (bench/ci_timing.md): compiling is most of it, so the builds are made for build time:
# clang (three quarters of gcc's build time here, below), -O1 (about half the compile time of -O2 under
# the sanitizers; the libraries at -O2 made the slowest test, test_loop_closure_gate, only ~20 %
# faster, which the longer build ate up), line tables only (enough for symbolised stack traces, a
# third of the object size of -g), and only the targets the tests need (no benchmarks, no tool that
# no test runs).  No precompiled headers
# (cmake/precompiled_headers.cmake): with them the fresh-clone run of session 37 took longer here
# (ASan+UBSan build 1188 -> 1232 s, TSan build 261 -> 367 s: the TSan stage then also builds the
# test that makes the shared set, and instrumented code generation, not parsing, dominates).
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WHICH="${1:-all}"
export PYENV_VERSION=system ROS_HOSTNAME=localhost
# Sanitizer builds: -O1 and line tables only (see above); NDEBUG as in the Release build the same
# tests run in.
# Compiler: clang by default (TORO_SANITIZER_COMPILER=gcc for gcc).  Why: on the 2-core CI machine
# clang built the whole ASan+UBSan suite in 394 s where gcc took 531 s (session 38, the same
# machine and hour, nothing else running; bench/ci_timing.md).  The normal build stays on gcc, so
# two compilers check the code (clang's warnings found two unused variables).
SANITIZER_COMPILER="${TORO_SANITIZER_COMPILER:-clang}"
case "${SANITIZER_COMPILER}" in
  gcc) SANITIZER_FLAGS="-O1 -g1 -DNDEBUG" COMPILERS=(-DCMAKE_C_COMPILER=gcc -DCMAKE_CXX_COMPILER=g++) ;;
  clang) SANITIZER_FLAGS="-O1 -gline-tables-only -DNDEBUG" COMPILERS=(-DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++) ;;
  *) echo "sanitize.sh: TORO_SANITIZER_COMPILER must be gcc or clang" >&2; exit 2 ;;
esac

absolute() { [[ "$1" = /* ]] && printf '%s' "$1" || printf '%s/%s' "${REPO_ROOT}" "$1"; }

# configureAndBuild <build dir> <sanitizer> <targets>
configureAndBuild() {
  mkdir -p "$1"
  cmake -S "${REPO_ROOT}" -B "$1" "${COMPILERS[@]}" -DTORO_SANITIZER="$2" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="${SANITIZER_FLAGS}" -DCMAKE_C_FLAGS_RELWITHDEBINFO="${SANITIZER_FLAGS}" \
    -DTORO_PRECOMPILED_HEADERS=OFF \
    -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3 >"$1/sanitize-configure.log" 2>&1 </dev/null ||
    { tail -n 40 "$1/sanitize-configure.log" >&2; return 1; }
  TORO_BUILD_DIR="$1" TORO_BUILD_TYPE=RelWithDebInfo TORO_BUILD_TARGETS="$3" \
    bash "${REPO_ROOT}/scripts/build.sh" >"$1/sanitize-build.log" 2>&1 </dev/null ||
    { tail -n 40 "$1/sanitize-build.log" >&2; return 1; }
}

# checkReports <build dir> <name>: fails if any sanitizer report was written.
checkReports() {
  local reports=("$1"/sanitizer-reports/report.*)
  if [[ -e "${reports[0]}" ]]; then
    echo "sanitize.sh: $2 reported problems (${#reports[@]} report file(s) in $1/sanitizer-reports):" >&2
    head -n 60 "${reports[@]}" >&2
    return 1
  fi
  echo "sanitize.sh: $2: no sanitizer report"
}

# stageTime <name> <start seconds>
stageTime() { echo "sanitize.sh: $1 took $(($(date +%s) - $2)) s"; }

runAddress() {
  local build start
  build="$(absolute "${TORO_ASAN_BUILD_DIR:-build-asan}")"
  start=$(date +%s)
  echo "sanitize.sh: ASan+UBSan build of every test in ${build}"
  # `tests` builds every test executable and, through their dependencies, the node, tools and the
  # sample bag the tests run; the messages' Python side is for the rostests' Python helpers.
  configureAndBuild "${build}" address "tests toro_ros_generate_messages"
  stageTime "ASan+UBSan build" "${start}"
  rm -rf "${build}/sanitizer-reports" && mkdir -p "${build}/sanitizer-reports"
  local common="log_path=${build}/sanitizer-reports/report"
  start=$(date +%s)
  (cd "${build}" &&
    ASAN_OPTIONS="${common}:detect_leaks=1:suppressions=${REPO_ROOT}/test/sanitizers/asan.supp" \
    LSAN_OPTIONS="suppressions=${REPO_ROOT}/test/sanitizers/lsan.supp" \
    UBSAN_OPTIONS="${common}:print_stacktrace=1:halt_on_error=1" \
    ctest --output-on-failure -E 'graph_topics_nodelet' </dev/null)
  stageTime "ASan+UBSan ctest" "${start}"
  checkReports "${build}" "ASan+UBSan"
}

runThread() {
  local build start targets pattern
  build="$(absolute "${TORO_TSAN_BUILD_DIR:-build-tsan}")"
  # The worker thread tests (the other gtests run no threads of ours).
  targets="test_pipeline_worker"
  pattern='test_pipeline_worker$'
  if [[ "${TORO_TSAN_ROSTEST:-0}" != 0 ]]; then
    targets="${targets} toro_ros_generate_messages map_corrector_node map_corrector"
    pattern="${pattern}|rostest_test_node_map_corrector"
  fi
  start=$(date +%s)
  echo "sanitize.sh: TSan build of ${targets} in ${build}"
  # Only what the selected tests need: the rest of the suite runs no threads of ours.
  configureAndBuild "${build}" thread "${targets}"
  stageTime "TSan build" "${start}"
  rm -rf "${build}/sanitizer-reports" && mkdir -p "${build}/sanitizer-reports"
  start=$(date +%s)
  (cd "${build}" &&
    TSAN_OPTIONS="log_path=${build}/sanitizer-reports/report:second_deadlock_stack=1:suppressions=${REPO_ROOT}/test/sanitizers/tsan.supp" \
    ctest --output-on-failure --no-tests=error -R "${pattern}" </dev/null)
  stageTime "TSan ctest" "${start}"
  checkReports "${build}" "TSan"
}

case "${WHICH}" in
  address) runAddress ;;
  thread) runThread ;;
  all) runAddress && runThread ;;
  *) echo "usage: scripts/sanitize.sh [address|thread|all]" >&2; exit 2 ;;
esac
