# vislam's own compile and link flags, as one INTERFACE target (vl_build_flags) that every target
# vislam defines links PRIVATE: warnings (-Werror with VL_WERROR), -march=native (VL_NATIVE) and the
# sanitizer or fuzzing instrumentation. Target-level, never directory-wide, so a project that builds
# vislam inside itself gets none of them on its own targets, and they are never exported.
add_library(vl_build_flags INTERFACE)
target_compile_options(vl_build_flags INTERFACE -Wall -Wextra)
if(VL_WERROR)
  target_compile_options(vl_build_flags INTERFACE -Werror)
endif()
if(VL_NATIVE)
  target_compile_options(vl_build_flags INTERFACE -march=native)
endif()

# Sanitizers apply to every target, so the tests exercise the same code they do in a plain build.
# The heap-allocation counters (test_alloc, the daemon test's LD_PRELOAD counter) replace malloc,
# which AddressSanitizer owns: under ASan they are left out (VL_ASAN), and the plain build runs them.
# VL_INSTRUMENTED: any sanitizer or the fuzzing build, where the code runs many times slower.
set(VL_ASAN OFF)
set(VL_INSTRUMENTED OFF)
if(VL_FUZZ OR NOT VL_SANITIZE STREQUAL "")
  set(VL_INSTRUMENTED ON)
endif()
if(VL_FUZZ)
  if(NOT CMAKE_C_COMPILER_ID MATCHES "Clang" OR NOT CMAKE_CXX_COMPILER_ID MATCHES "Clang")
    message(FATAL_ERROR "VL_FUZZ=ON needs clang (libFuzzer): configure with CC=clang CXX=clang++")
  endif()
  if(NOT VL_SANITIZE STREQUAL "")
    message(FATAL_ERROR "VL_FUZZ=ON already builds with address,undefined: leave VL_SANITIZE empty")
  endif()
  # Coverage instrumentation everywhere; only the fuzz executables link libFuzzer's main.
  target_compile_options(vl_build_flags INTERFACE -fsanitize=fuzzer-no-link,address,undefined
                         -fno-sanitize-recover=undefined -fno-omit-frame-pointer -g)
  target_link_options(vl_build_flags INTERFACE -fsanitize=address,undefined)
  set(VL_ASAN ON)
elseif(NOT VL_SANITIZE STREQUAL "")
  target_compile_options(vl_build_flags INTERFACE -fsanitize=${VL_SANITIZE} -fno-omit-frame-pointer -g)
  target_link_options(vl_build_flags INTERFACE -fsanitize=${VL_SANITIZE})
  if(VL_SANITIZE MATCHES "undefined")
    target_compile_options(vl_build_flags INTERFACE -fno-sanitize-recover=undefined)
  endif()
  if(VL_SANITIZE MATCHES "address")
    set(VL_ASAN ON)
  endif()
endif()

# vl_apply_build_flags(DIR): links vl_build_flags into every compiled target defined in DIR and
# its subdirectories (called once, after all of vislam's add_subdirectory calls), so a new target
# gets vislam's flags without being listed anywhere. BUILD_INTERFACE: static libraries carry
# their PRIVATE links into their link interface, and the installed package must not name it.
function(vl_apply_build_flags dir)
  get_property(targets DIRECTORY ${dir} PROPERTY BUILDSYSTEM_TARGETS)
  foreach(target ${targets})
    get_target_property(type ${target} TYPE)
    if(type MATCHES "^(EXECUTABLE|STATIC_LIBRARY|SHARED_LIBRARY|MODULE_LIBRARY|OBJECT_LIBRARY)$")
      target_link_libraries(${target} PRIVATE $<BUILD_INTERFACE:vl_build_flags>)
    endif()
  endforeach()
  get_property(subdirs DIRECTORY ${dir} PROPERTY SUBDIRECTORIES)
  foreach(subdir ${subdirs})
    vl_apply_build_flags(${subdir})
  endforeach()
endfunction()
