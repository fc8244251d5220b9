# install(EXPORT ...) so that an embedding project can find_package(pbgi) and link pbgi::pbgi.
include(GNUInstallDirs)
include(CMakePackageConfigHelpers)

get_property(_pbgi_modules GLOBAL PROPERTY PBGI_MODULES)
install(TARGETS ${_pbgi_modules} pbgi pbgi_warnings pbgi_sanitize
        EXPORT pbgiTargets
        ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
        LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
        INCLUDES DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
install(DIRECTORY include/pbgi DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
install(EXPORT pbgiTargets NAMESPACE pbgi:: DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/pbgi)

configure_package_config_file(cmake/pbgiConfig.cmake.in
  ${CMAKE_CURRENT_BINARY_DIR}/pbgiConfig.cmake
  INSTALL_DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/pbgi)
write_basic_package_version_file(${CMAKE_CURRENT_BINARY_DIR}/pbgiConfigVersion.cmake
  COMPATIBILITY SameMinorVersion)
install(FILES ${CMAKE_CURRENT_BINARY_DIR}/pbgiConfig.cmake
              ${CMAKE_CURRENT_BINARY_DIR}/pbgiConfigVersion.cmake
        DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/pbgi)
