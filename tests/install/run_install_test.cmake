# cmake -P script behind the install_consumer test. Inputs: PBGI_BUILD_DIR, CONSUMER_SOURCE_DIR,
# WORK_DIR, GENERATOR, CXX_COMPILER.
foreach(var PBGI_BUILD_DIR CONSUMER_SOURCE_DIR WORK_DIR GENERATOR CXX_COMPILER)
  if(NOT DEFINED ${var})
    message(FATAL_ERROR "run_install_test.cmake: ${var} is not set")
  endif()
endforeach()

function(step name)
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "install_consumer: ${name} failed (${rc}):\n${out}\n${err}")
  endif()
  message(STATUS "install_consumer: ${name}: ok")
  set(step_output "${out}" PARENT_SCOPE)
endfunction()

file(REMOVE_RECURSE "${WORK_DIR}")
file(MAKE_DIRECTORY "${WORK_DIR}")
step("cmake --install" ${CMAKE_COMMAND} --install "${PBGI_BUILD_DIR}" --prefix "${WORK_DIR}/prefix")
if(NOT EXISTS "${WORK_DIR}/prefix/include/pbgi/store.h")
  message(FATAL_ERROR "install_consumer: the public headers were not installed")
endif()
step("configure consumer" ${CMAKE_COMMAND} -S "${CONSUMER_SOURCE_DIR}" -B "${WORK_DIR}/build"
     -G "${GENERATOR}" -DCMAKE_BUILD_TYPE=Release "-DCMAKE_CXX_COMPILER=${CXX_COMPILER}"
     "-DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix")
step("build consumer" ${CMAKE_COMMAND} --build "${WORK_DIR}/build")
step("run consumer" "${WORK_DIR}/build/pbgi_consumer" "${WORK_DIR}/db")
if(NOT step_output MATCHES "consumer: ok")
  message(FATAL_ERROR "install_consumer: unexpected output: ${step_output}")
endif()
message(STATUS "${step_output}")
file(REMOVE_RECURSE "${WORK_DIR}")
