#!/bin/sh
# Node latency benchmark (issue 4): a private roscore, map_corrector_node with every odometry
# message a keyframe and full rounds off (so map->odom changes only through loop closures), and
# the bench client.  Usage: bench/node/run_node_bench.sh <build dir> [keyframes] [rate_hz] [lap]
# Environment: REVISIT loop closures per revisit (default 3; the node's support releases a
# revisit at its third), SUPPORT=false to apply each loop closure at once
# (robust_hold_until_supported), FINISH and FULL_ITERATIONS as below.
set -e
BUILD=${1:?build dir}
KEYFRAMES=${2:-20000}
RATE=${3:-100}
LAP=${4:-500}
PORT=${TORO_BENCH_PORT:-11471}
export PYENV_VERSION=system ROS_HOSTNAME=localhost ROS_MASTER_URI=http://localhost:$PORT
. "$BUILD/devel/setup.sh"
roscore -p "$PORT" >/dev/null 2>&1 &
CORE=$!
trap 'kill $NODE 2>/dev/null; kill $CORE 2>/dev/null' EXIT
until rosparam list >/dev/null 2>&1; do sleep 0.2; done
rosparam set /use_sim_time false
rosparam set /map_corrector/keyframe_distance_m 0.005
rosparam set /map_corrector/keyframe_angle_rad 1.0
# FULL_ITERATIONS > 0 turns the scheduled full rounds on (then map->odom also moves between loop
# closures and the latency attribution no longer holds: use it to check the queue only).
rosparam set /map_corrector/optimization_full_iterations "${FULL_ITERATIONS:-0}"
rosparam set /map_corrector/queue_size 100000
rosparam set /map_corrector/robust_hold_until_supported "${SUPPORT:-true}"
# FINISH=false turns the background finish off: its merges move map->odom too, so with it on a
# merge that lands between a revisit's publication and its own pass is counted as its answer.
rosparam set /map_corrector/optimization_background_finish "${FINISH:-true}"
"$BUILD/devel/lib/toro_ros/map_corrector_node" __name:=map_corrector >/dev/null 2>&1 &
NODE=$!
"$BUILD/devel/lib/toro_ros/bench_node_latency" "$KEYFRAMES" "$RATE" "$LAP" "$NODE" "${REVISIT:-3}"
