# Fuzz targets (test/fuzz/fuzz_*.cpp, each defining LLVMFuzzerTestOneInput).
# - Every build: a replay executable per target runs the committed corpus and the regression inputs
#   (crashes found earlier) through the target; it is a ctest test, so no compiler support is needed.
# - With clang and -DTORO_BUILD_FUZZERS=ON: real libFuzzer binaries (ASan+UBSan), run by scripts/fuzz.sh.
# A target that includes a toro_ros/pipeline header links the pipeline library (and so ROS'
# serialisation and message types); the others link only the core.
option(TORO_BUILD_FUZZERS "Build libFuzzer targets (needs clang)" OFF)
if(TORO_BUILD_FUZZERS)
  # libFuzzer's coverage feedback in the libraries the targets exercise.  Not in a build that also
  # runs the test suite: its comparison tracing made the ASan+UBSan suite's numeric tests 1.5-2.5
  # times slower (session 38: test_innovation_support 104 -> 261 s), more than a build of their
  # own costs (bench/ci_timing.md).
  target_compile_options(toro_core PRIVATE -fsanitize=fuzzer-no-link)
  target_compile_options(toro_pipeline PRIVATE -fsanitize=fuzzer-no-link)
endif()
file(GLOB TORO_FUZZ_SOURCES CONFIGURE_DEPENDS ${PROJECT_SOURCE_DIR}/test/fuzz/fuzz_*.cpp)
foreach(src ${TORO_FUZZ_SOURCES})
  get_filename_component(name ${src} NAME_WE)
  string(REGEX REPLACE "^fuzz_" "" target_name ${name})
  file(STRINGS ${src} uses_pipeline REGEX "#include \"toro_ros/pipeline/")
  if(uses_pipeline)
    set(fuzz_library toro_pipeline)
  else()
    set(fuzz_library toro_core)
  endif()
  if(CATKIN_ENABLE_TESTING)
    add_executable(${name}_replay ${src} ${PROJECT_SOURCE_DIR}/test/fuzz/replay_main.cpp)
    target_link_libraries(${name}_replay ${fuzz_library})
    add_dependencies(tests ${name}_replay)
    add_test(NAME ${name}_replay
             COMMAND ${name}_replay ${PROJECT_SOURCE_DIR}/test/fuzz/corpus/${target_name}
                     ${PROJECT_SOURCE_DIR}/test/fuzz/regressions/${target_name})
  endif()
  if(TORO_BUILD_FUZZERS)
    if(NOT CMAKE_CXX_COMPILER_ID MATCHES "Clang")
      message(FATAL_ERROR "TORO_BUILD_FUZZERS needs clang (configure with -DCMAKE_CXX_COMPILER=clang++)")
    endif()
    add_executable(${name} ${src})
    target_compile_options(${name} PRIVATE -fsanitize=fuzzer,address,undefined)
    target_link_options(${name} PRIVATE -fsanitize=fuzzer,address,undefined)
    target_link_libraries(${name} ${fuzz_library})
  endif()
endforeach()
