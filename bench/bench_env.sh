# Sourced by the dataset benchmarks (bench/run_*_bench.sh): strict mode, and where things are.
#   root: the repository; build: $1 or build/; bin: its tools; datasets: ../shared/datasets;
#   work: a scratch directory removed on exit.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[1]}")/.." && pwd)
build=$(realpath "${1:-$root/build}")
bin=$build/devel/lib/toro_ros
datasets=$root/../shared/datasets
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
