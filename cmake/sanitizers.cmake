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
