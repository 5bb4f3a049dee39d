#!/bin/bash
# Headless rviz screenshot of a replay (what a user sees with `roslaunch toro_ros replay.launch
# bag:=... rviz:=true`): Xvfb + the replay at RATE x speed, a screenshot once the replay's
# finisher reports the saved graph (plus a few seconds for rviz to draw the latched path and
# markers), then everything is stopped.
#
#   scripts/rviz_screenshot.sh [BAG] [OUTPUT.png]
#     BAG     default: <build>/sample/sample.bag (the bundled sample, made at build time)
#     OUTPUT  default: out/rviz_replay.png
#   env: BUILD_DIR (default ./build), RATE (default 2), CONFIG (default config/replay_sample.yaml for
#        the sample, config/map_corrector.yaml otherwise), SETTLE_SEC (default 4)
# Needs xvfb and imagemagick (scripts/install_deps.sh installs them).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
build=${BUILD_DIR:-$root/build}
bag=$(realpath -m "${1:-$build/sample/sample.bag}")
out=$(realpath -m "${2:-$root/out/rviz_replay.png}")
rate=${RATE:-2}
settle=${SETTLE_SEC:-4}
if [[ -z "${CONFIG:-}" ]]; then
  if [[ "$bag" == "$build/sample/sample.bag" ]]; then CONFIG=$root/config/replay_sample.yaml
  else CONFIG=$root/config/map_corrector.yaml; fi
fi
[[ -f "$bag" ]] || { echo "rviz_screenshot.sh: no bag at $bag (build first: scripts/build.sh)" >&2; exit 1; }
[[ -f "$build/devel/setup.bash" ]] || { echo "rviz_screenshot.sh: no $build/devel/setup.bash (build first)" >&2; exit 1; }
command -v xvfb-run >/dev/null || { echo "rviz_screenshot.sh: xvfb-run missing (apt-get install xvfb)" >&2; exit 1; }
command -v import >/dev/null || { echo "rviz_screenshot.sh: import missing (apt-get install imagemagick)" >&2; exit 1; }
mkdir -p "$(dirname "$out")"

set +u  # the ROS setup files read unset variables
# shellcheck disable=SC1091
source "$build/devel/setup.bash"
set -u
export PYENV_VERSION=system ROS_HOSTNAME=localhost
# A master of our own on a free-ish port, so a running roscore is not disturbed.
port=$((11500 + RANDOM % 400))
export ROS_MASTER_URI=http://localhost:$port
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

xvfb-run -a -s "-screen 0 1280x900x24" bash -c '
  roslaunch -p '"$port"' toro_ros replay.launch bag:='"$bag"' config:='"$CONFIG"' rviz:=true rate:='"$rate"' \
    exit_when_done:=false output_dir:='"$work"' > '"$work"'/launch.log 2>&1 &
  launch=$!
  for _ in $(seq 100); do rostopic list >/dev/null 2>&1 && break; sleep 0.2; done
  if timeout 150 rostopic echo -n 1 /replay_finish/result > '"$work"'/result.txt 2>/dev/null; then
    sleep '"$settle"'
    import -window root -crop 1200x800+0+0 +repage '"$out"'  # the rviz window (rviz/map_corrector.rviz geometry)
    status=0
  else
    echo "rviz_screenshot.sh: the replay did not finish; log: " >&2
    tail -20 '"$work"'/launch.log >&2
    status=1
  fi
  kill -TERM $launch 2>/dev/null  # (SIGINT is ignored by background jobs of a script)
  wait $launch 2>/dev/null
  exit $status'
grep -E "^replay_finish:|error vs truth|chi2 before" "$work/launch.log" || true
echo "wrote $out"
