# What `cmake --install` gives a project that builds on vislam (besides the programs, which their
# own folders install): the CMake package (find_package(vislam), targets vislam::core,
# vislam::headers and, with LCM, vislam::lcm_types) and pkg-config files (vislam, vislam-lcm);
# with VL_CORE_ONLY the core's alone.
# The core and header install rules are in core/, the message types' in lcm_types/.
include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

set(VL_CMAKE_INSTALL_DIR ${CMAKE_INSTALL_LIBDIR}/cmake/vislam)
install(EXPORT vislam-core-targets NAMESPACE vislam:: FILE vislamCoreTargets.cmake
        DESTINATION ${VL_CMAKE_INSTALL_DIR})
if(NOT VL_CORE_ONLY)
  install(EXPORT vislam-lcm-targets NAMESPACE vislam:: FILE vislamLcmTargets.cmake
          DESTINATION ${VL_CMAKE_INSTALL_DIR})
endif()
configure_package_config_file(${CMAKE_CURRENT_LIST_DIR}/vislamConfig.cmake.in
                              ${PROJECT_BINARY_DIR}/cmake/vislamConfig.cmake
                              INSTALL_DESTINATION ${VL_CMAKE_INSTALL_DIR})
# 0.x: a minor version may change the API.
write_basic_package_version_file(${PROJECT_BINARY_DIR}/cmake/vislamConfigVersion.cmake
                                 COMPATIBILITY SameMinorVersion)
install(FILES ${PROJECT_BINARY_DIR}/cmake/vislamConfig.cmake ${PROJECT_BINARY_DIR}/cmake/vislamConfigVersion.cmake
        DESTINATION ${VL_CMAKE_INSTALL_DIR})

# pkg-config files find their prefix from their own place (${pcfiledir}), so an install made with
# `cmake --install BUILD --prefix DIR` works wherever DIR is.
if(IS_ABSOLUTE "${CMAKE_INSTALL_LIBDIR}" OR IS_ABSOLUTE "${CMAKE_INSTALL_INCLUDEDIR}")
  message(FATAL_ERROR "vislam's pkg-config files need CMAKE_INSTALL_LIBDIR and CMAKE_INSTALL_INCLUDEDIR relative to the prefix")
endif()
file(RELATIVE_PATH VL_PC_PREFIX_FROM_PCFILEDIR /prefix/${CMAKE_INSTALL_LIBDIR}/pkgconfig /prefix)
set(VL_PC_FILES vislam)
if(NOT VL_CORE_ONLY)
  list(APPEND VL_PC_FILES vislam-lcm)
endif()
foreach(pc ${VL_PC_FILES})
  configure_file(${CMAKE_CURRENT_LIST_DIR}/${pc}.pc.in ${PROJECT_BINARY_DIR}/pkgconfig/${pc}.pc @ONLY)
  install(FILES ${PROJECT_BINARY_DIR}/pkgconfig/${pc}.pc DESTINATION ${CMAKE_INSTALL_LIBDIR}/pkgconfig)
endforeach()
