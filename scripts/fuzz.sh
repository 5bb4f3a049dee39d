#!/usr/bin/env bash
# Runs every libFuzzer target (test/fuzz/fuzz_*.cpp) for a fixed time, seeded with the committed
# corpus. A crash is copied into test/fuzz/regressions/<target>/ (commit it: ctest replays it from
# then on) and the script fails.
#   scripts/fuzz.sh [SECONDS_PER_TARGET]      (default 60; TORO_FUZZ_BUILD_DIR, default build-fuzz)
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-60}"
build="${TORO_FUZZ_BUILD_DIR:-build-fuzz}"
export PYENV_VERSION=system ROS_HOSTNAME=localhost
command -v clang++ >/dev/null || { echo "fuzz.sh: clang++ not found (scripts/install_deps.sh installs it)" >&2; exit 2; }
cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
  -DCMAKE_CXX_FLAGS="-fsanitize=fuzzer-no-link,address,undefined" -DTORO_BUILD_FUZZERS=ON \
  -DCATKIN_ENABLE_TESTING=OFF -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3 >/dev/null
status=0
for src in test/fuzz/fuzz_*.cpp; do
  name=$(basename "$src" .cpp)
  target=${name#fuzz_}
  cmake --build "$build" -j2 --target "$name" >/dev/null
  work="out/fuzz/$target"
  artifacts="out/fuzz/$target-artifacts"
  mkdir -p "$work" "$artifacts"
  echo "fuzzing $target for ${seconds}s"
  if ! "$build/devel/lib/toro_ros/$name" "$work" "test/fuzz/corpus/$target" -max_total_time="$seconds" \
        -max_len=16384 -artifact_prefix="$artifacts/" -print_final_stats=1 2>"out/fuzz/$target.log"; then
    status=1
    for crash in "$artifacts"/*; do
      [ -f "$crash" ] || continue
      cp "$crash" "test/fuzz/regressions/$target/"
      echo "fuzz.sh: $target failed on $(basename "$crash"), copied to test/fuzz/regressions/$target/" >&2
    done
    tail -n 30 "out/fuzz/$target.log" >&2
  else
    grep -E "stat::number_of_executed_runs|cov:" "out/fuzz/$target.log" | tail -n 2
  fi
done
exit $status
