# Writes the version header (cmake -P): -DSOURCE_DIR= -DINPUT= -DOUTPUT= -DPROJECT_VERSION=.
# Run at every build (the vislam_version target), so the git description follows commits and edits
# without a re-configure; configure_file rewrites OUTPUT only when its text changes, so an
# unchanged description rebuilds nothing.
set(VL_VERSION_PROJECT "${PROJECT_VERSION}")
set(VL_VERSION_GIT "")
find_program(VL_GIT git)
if(VL_GIT)
  # Only the source tree's own repository: a release tarball unpacked inside another checkout
  # must not take that checkout's description.
  execute_process(COMMAND ${VL_GIT} -C ${SOURCE_DIR} rev-parse --show-toplevel
                  OUTPUT_VARIABLE top RESULT_VARIABLE rc OUTPUT_STRIP_TRAILING_WHITESPACE ERROR_QUIET)
  if(rc EQUAL 0)
    get_filename_component(top "${top}" REALPATH)
    get_filename_component(src "${SOURCE_DIR}" REALPATH)
    if(top STREQUAL src)
      execute_process(COMMAND ${VL_GIT} -C ${SOURCE_DIR} describe --always --dirty
                      OUTPUT_VARIABLE describe RESULT_VARIABLE rc OUTPUT_STRIP_TRAILING_WHITESPACE ERROR_QUIET)
      if(rc EQUAL 0)
        set(VL_VERSION_GIT "${describe}")
      endif()
    endif()
  endif()
endif()
configure_file(${INPUT} ${OUTPUT} @ONLY)
