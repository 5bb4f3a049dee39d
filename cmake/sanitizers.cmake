# Sanitizer builds for the whole package: -DTORO_SANITIZER=address (AddressSanitizer +
# UndefinedBehaviorSanitizer) or -DTORO_SANITIZER=thread (ThreadSanitizer).  Included before any
# target is defined so that every library, tool and test is instrumented alike.
set(TORO_SANITIZER "" CACHE STRING "Sanitizer build: empty, 'address' (ASan+UBSan) or 'thread' (TSan)")
set_property(CACHE TORO_SANITIZER PROPERTY STRINGS "" address thread)
if(TORO_SANITIZER STREQUAL "address")
  add_compile_options(-fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined)
  add_link_options(-fsanitize=address,undefined)
elseif(TORO_SANITIZER STREQUAL "thread")
  add_compile_options(-fsanitize=thread -fno-omit-frame-pointer)
  add_link_options(-fsanitize=thread)
elseif(NOT TORO_SANITIZER STREQUAL "")
  message(FATAL_ERROR "TORO_SANITIZER must be empty, 'address' or 'thread', not '${TORO_SANITIZER}'")
endif()
# Extra compile flags for the shared libraries only (appended after the build type's flags, so they
# win).  scripts/sanitize.sh builds everything at -O1 (half the compile time of -O2 under the
# sanitizers) but the libraries at -O2: they hold the numerics the tests spend their time in, and at
# -O1 GCC leaves Eigen's small quaternion/matrix functions out of line, which made
# test_loop_closure_gate ~100x slower than in Release (bench/ci_timing.md).
set(TORO_SANITIZER_LIBRARY_FLAGS "" CACHE STRING "Extra compile flags for the shared libraries (e.g. -O2)")
if(TORO_SANITIZER_LIBRARY_FLAGS)
  separate_arguments(toro_sanitizer_library_flags UNIX_COMMAND "${TORO_SANITIZER_LIBRARY_FLAGS}")
  add_compile_options("$<$<STREQUAL:$<TARGET_PROPERTY:TYPE>,SHARED_LIBRARY>:${toro_sanitizer_library_flags}>")
endif()
