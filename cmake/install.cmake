# install(EXPORT ...) so that an embedding project can find_package(pbgi) and link pbgi::pbgi.
# Three export sets, one per part of the package (see cmake/pbgiConfig.cmake.in):
#  - core (pbgiTargets): pbgi::pbgi and the modules it links; needs absl, GLM, LMDB and TBB; also
#    the C API: pbgi::capi (static, a module) and pbgi::c (libpbgi_c.so, for C programs);
#  - scene (pbgiSceneTargets): procedural scenes, mesh import, Embree tracing; Embree, Assimp;
#  - testing (pbgiTestingTargets): the query test harness of pbgi/testing.h.
include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

set(_pbgi_cmake_dir ${CMAKE_INSTALL_LIBDIR}/cmake/pbgi)
get_property(_pbgi_core GLOBAL PROPERTY PBGI_MODULES_core)
get_property(_pbgi_scene GLOBAL PROPERTY PBGI_MODULES_scene)
get_property(_pbgi_testing GLOBAL PROPERTY PBGI_MODULES_testing)
foreach(set core scene testing)
  if(set STREQUAL core)
    get_property(_pbgi_c GLOBAL PROPERTY PBGI_C_LIBRARY)
    set(_targets ${_pbgi_core} ${_pbgi_c} pbgi pbgi_warnings pbgi_sanitize)
    set(_export pbgiTargets)
  elseif(set STREQUAL scene)
    set(_targets ${_pbgi_scene})
    set(_export pbgiSceneTargets)
  else()
    set(_targets ${_pbgi_testing})
    set(_export pbgiTestingTargets)
  endif()
  install(TARGETS ${_targets}
          EXPORT ${_export}
          ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
          LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
          INCLUDES DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
  install(EXPORT ${_export} NAMESPACE pbgi:: DESTINATION ${_pbgi_cmake_dir})
endforeach()
install(DIRECTORY include/pbgi DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})

configure_package_config_file(cmake/pbgiConfig.cmake.in
  ${CMAKE_CURRENT_BINARY_DIR}/pbgiConfig.cmake
  INSTALL_DESTINATION ${_pbgi_cmake_dir})
write_basic_package_version_file(${CMAKE_CURRENT_BINARY_DIR}/pbgiConfigVersion.cmake
  COMPATIBILITY SameMinorVersion)
install(FILES ${CMAKE_CURRENT_BINARY_DIR}/pbgiConfig.cmake
              ${CMAKE_CURRENT_BINARY_DIR}/pbgiConfigVersion.cmake
        DESTINATION ${_pbgi_cmake_dir})
