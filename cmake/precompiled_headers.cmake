# Precompiled headers.  Why: most of a source's compile time here is parsing the same headers
# (ROS messages and roscpp, Eigen, gtest): test/pipeline/test_pipeline_planar.cpp spends 65 % of
# its compile in parsing and 20 % instantiating what the headers declare (g++ -ftime-report), and
# the package compiles each source up to four times in CI (normal, catkin workspace, ASan+UBSan and
# TSan builds; bench/ci_timing.md).  With the sets below a test's compile takes 15-40 % less
# (test_pipeline_planar 12.7 -> 8.0 s, test_live_options 20.7 -> 14.7 s, -O3).  A library
# precompiles its kind's set for its own sources; the test executables
# (one source each) share one set per kind, made by the first test of that kind (a library's
# cannot serve them: it is compiled position-independent).  The sets are pre-included, so a source
# that forgets an include still compiles here: scripts/fuzz.sh and scripts/sanitize.sh build with
# TORO_PRECOMPILED_HEADERS=OFF, which checks it (and the sanitizer builds were no faster with
# them; bench/ci_timing.md).
option(TORO_PRECOMPILED_HEADERS "Precompile the headers most sources parse" ON)

# The core's set: the standard library and Eigen parts nearly every core source uses.  No ROS
# header (the core's rule; test_core_has_no_ros).
set(TORO_PCH_CORE <algorithm> <cmath> <cstddef> <memory> <string> <unordered_map> <vector>
    <Eigen/Core> <Eigen/Geometry> <Eigen/Cholesky> ${PROJECT_SOURCE_DIR}/include/toro_ros/core/pose_graph.h)
# The ROS-facing layers' set (pipeline, node, offline): roscpp and the message types they exchange.
set(TORO_PCH_ROS ${TORO_PCH_CORE} <ros/ros.h> <nav_msgs/Odometry.h> <geometry_msgs/PoseStamped.h>
    <geometry_msgs/TransformStamped.h> ${PROJECT_SOURCE_DIR}/include/toro_ros/pipeline/pipeline.h)

# toro_library_pch(<target> CORE|ROS): the library's own precompiled set (one per library: CMake
# defines <target>_EXPORTS in each shared library's sources, so another library's set would be
# rejected, -Winvalid-pch).
function(toro_library_pch target kind)
  if(TORO_PRECOMPILED_HEADERS)
    target_precompile_headers(${target} PRIVATE ${TORO_PCH_${kind}})
  endif()
endfunction()

# toro_test_pch(<target> CORE|ROS): a one-source test executable takes the set of its kind (and
# gtest) from the first test of that kind, which precompiles it.
function(toro_test_pch target kind)
  if(NOT TORO_PRECOMPILED_HEADERS)
    return()
  endif()
  get_property(donor GLOBAL PROPERTY TORO_PCH_TEST_DONOR_${kind})
  if(donor)
    target_precompile_headers(${target} REUSE_FROM ${donor})
  else()
    target_precompile_headers(${target} PRIVATE ${TORO_PCH_${kind}} <gtest/gtest.h>)
    set_property(GLOBAL PROPERTY TORO_PCH_TEST_DONOR_${kind} ${target})
  endif()
endfunction()
