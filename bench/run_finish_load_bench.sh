#!/usr/bin/env bash
# The finish beside a two-job C++ build (issue 14, item 3): runs `toro_optimize` N times on a quiet
# machine and N times while this script keeps a `make -j2` build of this project's core sources
# running in a scratch directory, for each thread setting, and prints medians (finish wall, process
# wall and CPU) and the loaded / quiet ratio of the finish's wall time.
#
# A build and not a busy loop: compilers that start and end every few seconds are what slowed the
# finish (bench/finish_load_results.md); two steady busy loops did not.  For that comparison:
# `--load busy` (two busy loops), `busy4` (four, as many as CHOLMOD's OpenMP team), `churn` (two
# loops that each start a new 0.2 s CPU-bound process, again and again).
#
# usage: bench/run_finish_load_bench.sh [--runs N] [--load build|busy] [--mode finish|toro+finish]
#            [--setting 'LABEL|ENV=V ...|toro_optimize arguments[|PROGRAM]'] ... [FILE ...]
#   --load: build (default), busy, busy4, churn (see above).
#   FILE defaults to test/data/smallGrid3D.g2o, parking-garage.g2o and sphere2500.g2o (../shared/datasets).
#   --setting may be repeated; default: the program's default threads ("default", no option) and the
#   libraries' own ("library", --solver-threads 0).  ENV is passed through env(1), e.g.
#   --setting 'omp-limit-1|OMP_THREAD_LIMIT=1|--solver-threads 0'; PROGRAM (default TORO_OPTIMIZE) times
#   another build of toro_optimize, e.g. an older commit's.
# Other users: before every run the script waits (up to TORO_WAIT_SEC, default 20 s) until no
# process outside its own session and its load's is running, so that "quiet" means quiet and
# "loaded" means this load only; runs that still had company are counted in the output.
# Environment: TORO_BUILD_DIR (default build), TORO_OPTIMIZE (the program to time; default the build's).  The machine's load (uptime) is printed with each block:
# on a shared machine "quiet" is only as quiet as the other users leave it.
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${TORO_BUILD_DIR:-build}"
[[ "${BUILD_DIR}" = /* ]] || BUILD_DIR="${REPO_ROOT}/${BUILD_DIR}"
OPTIMIZE="${TORO_OPTIMIZE:-${BUILD_DIR}/devel/lib/toro_ros/toro_optimize}"
DATASETS="$(cd "${REPO_ROOT}/.." && pwd)/shared/datasets"
RUNS=7
LOAD=build
MODE=finish
SETTINGS=()
FILES=()
while (($#)); do
  case "$1" in
    --runs) RUNS="$2"; shift 2 ;;
    --load) LOAD="$2"; shift 2 ;;
    --mode) MODE="$2"; shift 2 ;;
    --setting) SETTINGS+=("$2"); shift 2 ;;
    -h | --help) sed -n '2,19p' "${BASH_SOURCE[0]}"; exit 0 ;;
    *) FILES+=("$1"); shift ;;
  esac
done
((${#SETTINGS[@]})) || SETTINGS=("default||" "library||--solver-threads 0")
((${#FILES[@]})) || FILES=("${REPO_ROOT}/test/data/smallGrid3D.g2o" "${DATASETS}/parking-garage.g2o"
                           "${DATASETS}/sphere2500.g2o")
[[ -x "${OPTIMIZE}" ]] || { echo "no ${OPTIMIZE}: build first (or set TORO_BUILD_DIR)" >&2; exit 1; }
MODE_ARGS=(--mode "${MODE}")
[[ "${MODE}" == finish ]] && MODE_ARGS+=(--initial-guess file)

SCRATCH="$(mktemp -d /tmp/toro_finish_load.XXXXXX)"
LOAD_PID=""
WAIT_SEC="${TORO_WAIT_SEC:-20}"
DISTURBED=0

OWN_SID="$(ps -o sid= -p $$ | tr -d ' ')"

# Processes running or runnable now outside this script's session and its load's (kernel threads,
# session 0, aside).
foreignRunnable() {
  ps -eo sid=,stat= | awk -v a="${OWN_SID}" -v b="${LOAD_PID:-none}" '$1 != 0 && $1 != a && $1 != b && $2 ~ /^R/' | wc -l
}

# Waits until two samples 0.1 s apart see no other user's process running.
waitForQuiet() {
  local waited=0 clear=0
  while ((clear < 2)); do
    if (($(foreignRunnable) == 0)); then clear=$((clear + 1)); else clear=0; fi
    ((clear < 2)) && sleep 0.1
    waited=$((waited + 1))
    if ((waited >= WAIT_SEC * 10)); then
      DISTURBED=$((DISTURBED + 1))
      return
    fi
  done
}

stopLoad() {
  # The load runs in its own session (setsid), so its process group id is its pid: this ends the
  # make loop and the compilers it started, and nothing else.
  if [[ -n "${LOAD_PID}" ]]; then
    kill -TERM -- "-${LOAD_PID}" 2>/dev/null || true
    wait "${LOAD_PID}" 2>/dev/null || true
    LOAD_PID=""
  fi
}
trap 'stopLoad; rm -rf "${SCRATCH}"' EXIT

# Two jobs that compile the core's translation units (Eigen-heavy, 2-10 s each) again and again.
writeBuild() {
  mkdir -p "${SCRATCH}/obj"
  {
    echo "SRCS := \$(wildcard ${REPO_ROOT}/src/core/*.cpp)"
    echo "OBJS := \$(patsubst ${REPO_ROOT}/src/core/%.cpp,obj/%.o,\$(SRCS))"
    echo "all: \$(OBJS)"
    echo "obj/%.o: ${REPO_ROOT}/src/core/%.cpp"
    printf '\t%s\n' "g++ -std=c++17 -O2 -DTORO_HAVE_CHOLMOD -I${REPO_ROOT}/include -I${REPO_ROOT}/src/core -I/usr/include/eigen3 -I/usr/include/suitesparse -c \$< -o \$@"
  } >"${SCRATCH}/Makefile"
}

startLoad() {
  case "${LOAD}" in
    build)
      writeBuild
      setsid bash -c "cd '${SCRATCH}' && while :; do rm -f obj/*.o; make -s -j2 >/dev/null 2>&1; done" &
      ;;
    busy)
      setsid bash -c 'while :; do :; done & while :; do :; done & wait' &
      ;;
    busy4)
      setsid bash -c 'for j in 1 2 3 4; do (while :; do :; done) & done; wait' &
      ;;
    churn)
      setsid bash -c 'for j in 1 2; do (while :; do awk "BEGIN { for (i = 0; i < 4e6; ++i) s += i }"; done) & done; wait' &
      ;;
    *) echo "unknown --load ${LOAD}" >&2; exit 2 ;;
  esac
  LOAD_PID=$!
  sleep 5  # past the first compiler start-ups: the steady state of the build
}

# One run; prints "finish_wall process_wall process_cpu" (seconds).
measureOnce() {
  local file="$1" env_text="$2" args_text="$3" program="${4:-${OPTIMIZE}}" out real user sys fin
  local -a env_args=() extra=()
  read -r -a env_args <<<"${env_text}"
  read -r -a extra <<<"${args_text}"
  waitForQuiet
  out="$( { TIMEFORMAT='%R %U %S'; time env ${env_args[@]+"${env_args[@]}"} "${program}" -q "${MODE_ARGS[@]}" \
    ${extra[@]+"${extra[@]}"} "${file}" >"${SCRATCH}/stdout" </dev/null; } 2>&1)"
  read -r real user sys <<<"${out}"
  fin="$(grep -o 'optimisation [0-9.e+-]* s' "${SCRATCH}/stdout" | awk '{print $2}')"
  echo "${fin} ${real} $(awk -v u="${user}" -v s="${sys}" 'BEGIN{print u + s}')"
}

median() { sort -g | awk '{v[NR] = $1} END {print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2}'; }
column() { awk -v c="$1" '{print $c}' "$2" | median; }

echo "toro_optimize ${MODE_ARGS[*]}, ${RUNS} runs per cell (medians), load: ${LOAD}$([[ "${LOAD}" == build ]] && echo " (make -j2 of src/core, again and again)")"
echo "commit $(git -C "${REPO_ROOT}" rev-parse --short HEAD 2>/dev/null || echo unknown), $(date -u '+%Y-%m-%d %H:%M UTC'), $(nproc) CPUs"
echo
for phase in quiet loaded; do
  [[ "${phase}" == loaded ]] && startLoad
  DISTURBED=0
  waitForQuiet
  echo "${phase}: $(uptime | sed 's/.*load/load/') (before its first run)"
  # Settings in turn within each round, so that a disturbance falls on all of them alike.
  for file in "${FILES[@]}"; do
    for ((k = 0; k < RUNS; ++k)); do
      for s in "${SETTINGS[@]}"; do
        IFS='|' read -r label env_text args_text program <<<"${s}"
        measureOnce "${file}" "${env_text}" "${args_text}" "${program}" >>"${SCRATCH}/${phase}.$(basename "${file}").${label}"
      done
    done
  done
  echo "  ${phase}: ${DISTURBED} of $((RUNS * ${#SETTINGS[@]} * ${#FILES[@]} + 1)) waits (one per run, one before the first) ended with other users' processes still running (after ${WAIT_SEC} s)"
  stopLoad
done
echo "after: $(uptime | sed 's/.*load/load/')"
echo
echo "| file | setting | quiet finish s | quiet wall s | quiet CPU s | loaded finish s | loaded wall s | loaded CPU s | loaded / quiet (finish) |"
echo "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
for file in "${FILES[@]}"; do
  for s in "${SETTINGS[@]}"; do
    IFS='|' read -r label _ _ _ <<<"${s}"
    q="${SCRATCH}/quiet.$(basename "${file}").${label}"
    l="${SCRATCH}/loaded.$(basename "${file}").${label}"
    qf="$(column 1 "${q}")"; lf="$(column 1 "${l}")"
    printf '| %s | %s | %s | %s | %s | %s | %s | %s | %.2f |\n' "$(basename "${file}")" "${label}" \
      "${qf}" "$(column 2 "${q}")" "$(column 3 "${q}")" "${lf}" "$(column 2 "${l}")" "$(column 3 "${l}")" \
      "$(awk -v a="${lf}" -v b="${qf}" 'BEGIN{print a / b}')"
  done
done
