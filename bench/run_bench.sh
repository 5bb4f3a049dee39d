#!/usr/bin/env bash
# Builds and runs the optimiser benchmark, and writes bench/results.md (machine, date, commit and
# the exact command noted above the tables).  Arguments are passed to bench_toro (see the comment at
# the top of bench/bench_toro.cpp), e.g. `bash bench/run_bench.sh --only sphere2500 --no-synthetic`.
#
# Environment: TORO_BUILD_DIR (default build), TORO_BENCH_OUT (default bench/results.md),
# TORO_BENCH_E2E (default 1; 0 skips the end-to-end toro_optimize timing of the target datasets),
# TORO_BENCH_NICE (a niceness for the measured processes, e.g. -10 as root on a shared machine so
# that other jobs disturb the wall times less; noted in the results).
set -euo pipefail

REPO_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${TORO_BUILD_DIR:-build}"
[[ "${BUILD_DIR}" = /* ]] || BUILD_DIR="${REPO_ROOT}/${BUILD_DIR}"
OUT="${TORO_BENCH_OUT:-${REPO_ROOT}/bench/results.md}"
BENCH="${BUILD_DIR}/devel/lib/toro_ros/bench_toro"
OPTIMIZE="${BUILD_DIR}/devel/lib/toro_ros/toro_optimize"
DATASETS="$(cd "${REPO_ROOT}/.." && pwd)/shared/datasets"
E2E_RUNS=5
RUN_PREFIX=()
if [[ -n "${TORO_BENCH_NICE:-}" ]]; then RUN_PREFIX=(nice -n "${TORO_BENCH_NICE}"); fi

# The arguments as one would type them (quoted only where the shell needs it).
quotedArgs() {
  local a
  for a in "$@"; do
    if [[ "${a}" =~ ^[A-Za-z0-9_./,=:+-]+$ ]]; then printf ' %s' "${a}"; else printf " '%s'" "${a//\'/\'\\\'\'}"; fi
  done
}

# The whole toro_optimize process (start-up, read, setup, optimisation, the before/after metrics of
# its summary), as the original TORO program was timed: median wall and CPU over E2E_RUNS runs.
# `--mode toro -i 100` is the like-for-like comparison; the default mode adds the sparse finish.
endToEndRow() {
  local file="$1" t real user sys run
  shift
  local -a wall_list=() cpu_list=()
  for ((run = 0; run < E2E_RUNS; ++run)); do
    t="$( { TIMEFORMAT='%R %U %S'; time "${RUN_PREFIX[@]}" "${OPTIMIZE}" -q "$@" "${DATASETS}/${file}" >/dev/null </dev/null; } 2>&1)"
    read -r real user sys <<<"${t}"
    wall_list+=("${real}")
    cpu_list+=("$(awk -v u="${user}" -v s="${sys}" 'BEGIN {printf "%.3f", u + s}')")
  done
  local chi2
  chi2="$("${OPTIMIZE}" -q "$@" "${DATASETS}/${file}" </dev/null | awk '$1 == "after" {print $4}')"
  echo "| \`${OPTIMIZE#"${REPO_ROOT}"/} -q ${*:+$* }../shared/datasets/${file}\` | $(stats "${wall_list[@]}") |" \
    "$(stats "${cpu_list[@]}" | cut -d' ' -f1) | ${chi2} |"
}

endToEndTable() {
  local file
  echo "| command | wall (s), median [min, max] of ${E2E_RUNS} | CPU user+sys (s), median | g2o chi2 after |"
  echo "|---|---:|---:|---:|"
  for file in sphere2500.g2o parking-garage.g2o; do
    [[ -f "${DATASETS}/${file}" ]] || continue
    endToEndRow "${file}" --mode toro -i 100
    endToEndRow "${file}"
  done
}

# "median [min, max]" of the arguments.
stats() {
  printf '%s\n' "$@" | sort -g | awk '{v[NR] = $1} END {m = (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2; printf "%.3f [%.3f, %.3f]", m, v[1], v[NR]}'
}

TORO_BUILD_TARGETS="bench_toro toro_optimize" bash "${REPO_ROOT}/scripts/build.sh" </dev/null >&2

cpu_model="$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2- | sed 's/^ *//')"
memory="$(awk '/MemTotal/ {printf "%.1f GiB", $2 / 1048576}' /proc/meminfo)"
commit="$(git -C "${REPO_ROOT}" rev-parse --short HEAD 2>/dev/null || echo unknown)"
if [[ -n "$(git -C "${REPO_ROOT}" status --porcelain --untracked-files=no -- src include bench ':!bench/*.md' 2>/dev/null)" ]]; then
  commit="${commit} + uncommitted changes in src/include/bench"
fi
load_before="$(cut -d' ' -f1-3 /proc/loadavg)"

tables="$(mktemp)"
trap 'rm -f "${tables}"' EXIT
start=$(date +%s)
"${RUN_PREFIX[@]}" "${BENCH}" "$@" >"${tables}" </dev/null
elapsed=$(($(date +%s) - start))
e2e=""
if [[ "${TORO_BENCH_E2E:-1}" != 0 ]]; then e2e="$(endToEndTable)"; fi

{
  echo "# toro_ros benchmark results"
  echo
  echo "Written by \`${TORO_BENCH_NICE:+TORO_BENCH_NICE=${TORO_BENCH_NICE} }bash bench/run_bench.sh$(quotedArgs "$@")\`, which builds the \`bench_toro\` target"
  echo "(Release, see scripts/build.sh) and runs:"
  echo
  echo '```'
  echo "${RUN_PREFIX[*]}${RUN_PREFIX[*]:+ }${BENCH#"${REPO_ROOT}"/}$(quotedArgs "$@")"
  echo '```'
  echo
  echo "- Date: $(date -u '+%Y-%m-%d %H:%M UTC'); benchmark wall time ${elapsed} s"
  echo "- Machine: ${cpu_model}, $(nproc) cores (nproc), ${memory} RAM; $(uname -sr)"
  echo "- Compiler: $(c++ --version | head -1)"
  echo "- Code: commit ${commit}"
  echo "- Scheduling: niceness ${TORO_BENCH_NICE:-0} for the measured processes (lower = higher priority)."
  echo "- Load average (1/5/15 min) when the run started: ${load_before}. Other jobs share this machine,"
  echo "  so wall times carry noise; [min, max] over the runs shows how much."
  echo
  echo "How it measures (bench/bench_toro.cpp): each dataset runs in its own child process; in each of"
  echo "the timed runs the file is read, \`TreeOptimizer::setGraph\` builds the tree and the initial guess"
  echo "chained on the tree (the default), and \`iterate()\` runs the iterations; the median over the runs is"
  echo "reported. \"Whole run\" = read + setup + iterations, the quantity the targets refer to; its CPU"
  echo "time (the child's process CPU time over the same span) is shown beside it because it hardly"
  echo "grows when other jobs compete for the two cores, while wall time does. chi2 (g2o)"
  echo "and the SE-Sync objective are computed in one more, untimed run at the checkpoints (definitions in"
  echo "../shared/datasets/REFERENCE.md; never compare one measure with the other). Peak RSS is the child's"
  echo "ru_maxrss (it includes reading the file). TORO \`.graph\` files are read with the default EDGE3"
  echo "information order (translation first, as g2o and HOG-Man). 2D files are lifted into 3D (z = 0),"
  echo "measured with the 2D definitions and optimised in SE(2), the default for them; the last table runs"
  echo "them through the 3D code as well (Parameterization::kSpatial, its timed runs interleaved with the"
  echo "SE(2) ones, so both see the same load). The original-TORO figures come from issue 2."
  echo
  cat "${tables}"
  if [[ -n "${e2e}" ]]; then
    echo
    echo "## End to end: the toro_optimize process (start-up, read, setup, optimisation, summary metrics)"
    echo
    echo "${e2e}"
  fi
} >"${OUT}"
echo "run_bench.sh: wrote ${OUT}" >&2
