#!/usr/bin/env bash
# Runs every libFuzzer target (test/fuzz/fuzz_*.cpp) for a fixed time, seeded with the committed
# corpus. A crash is copied into test/fuzz/regressions/<target>/ (commit it: ctest replays it from
# then on) and the script fails. scripts/test.sh runs it with 20 s per target.
#   scripts/fuzz.sh [SECONDS_PER_TARGET]      (default 60; TORO_FUZZ_BUILD_DIR, default build-fuzz)
# The build uses clang (libFuzzer), ASan+UBSan, and the flags libFuzzer's documentation recommends
# (-O1 -gline-tables-only): quick to compile, and fast enough that a 20 s run does ~10^4 inputs.
# Without precompiled headers (-DTORO_PRECOMPILED_HEADERS=OFF): this build checks that the
# libraries' sources include what they use, which the pre-included sets of the other builds hide.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-60}"
build="${TORO_FUZZ_BUILD_DIR:-build-fuzz}"
export PYENV_VERSION=system ROS_HOSTNAME=localhost
command -v clang++ >/dev/null || { echo "fuzz.sh: clang++ not found (scripts/install_deps.sh installs it)" >&2; exit 2; }
start=$(date +%s)
mkdir -p "$build" out/fuzz
if ! cmake -S . -B "$build" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
    -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -gline-tables-only -DNDEBUG" -DCMAKE_C_FLAGS_RELWITHDEBINFO="-O1 -gline-tables-only -DNDEBUG" \
    -DTORO_SANITIZER=address -DTORO_BUILD_FUZZERS=ON \
    -DCATKIN_ENABLE_TESTING=OFF -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3 \
    -DTORO_PRECOMPILED_HEADERS=OFF \
    >"$build/fuzz-configure.log" 2>&1 </dev/null; then
  tail -n 40 "$build/fuzz-configure.log" >&2
  echo "fuzz.sh: configuring the fuzz build failed" >&2
  exit 2
fi
targets=()
for src in test/fuzz/fuzz_*.cpp; do targets+=("$(basename "$src" .cpp)"); done
if ! cmake --build "$build" -j"${TORO_JOBS:-2}" --target "${targets[@]}" >"$build/fuzz-build.log" 2>&1 </dev/null; then
  tail -n 40 "$build/fuzz-build.log" >&2
  echo "fuzz.sh: building the fuzz targets failed" >&2
  exit 2
fi
echo "fuzz.sh: built ${targets[*]} in $(($(date +%s) - start)) s"
status=0
for name in "${targets[@]}"; do
  target=${name#fuzz_}
  work="out/fuzz/$target"
  artifacts="out/fuzz/$target-artifacts"
  rm -rf "$artifacts"
  mkdir -p "$work" "$artifacts"
  echo "fuzz.sh: fuzzing $target for ${seconds}s"
  if ! "$build/devel/lib/toro_ros/$name" "$work" "test/fuzz/corpus/$target" -max_total_time="$seconds" \
        -max_len=16384 -artifact_prefix="$artifacts/" -print_final_stats=1 \
        2>"out/fuzz/$target.log" </dev/null; then
    status=1
    for crash in "$artifacts"/*; do
      [ -f "$crash" ] || continue
      cp "$crash" "test/fuzz/regressions/$target/"
      echo "fuzz.sh: $target failed on $(basename "$crash"), copied to test/fuzz/regressions/$target/" >&2
    done
    tail -n 30 "out/fuzz/$target.log" >&2
    echo "fuzz.sh: $target FAILED (log: out/fuzz/$target.log)" >&2
  else
    # libFuzzer's closing line, e.g. "Done 134112 runs in 21 second(s)" (a summary, not a check).
    grep -E "^Done [0-9]+ runs" "out/fuzz/$target.log" | tail -n 1 || true
  fi
done
echo "fuzz.sh: whole fuzz stage took $(($(date +%s) - start)) s"
exit $status
