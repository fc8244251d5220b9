# cmake -P script behind the install_consumer test. Inputs: PBGI_BUILD_DIR, CONSUMER_SOURCE_DIR,
# COMPONENTS_SOURCE_DIR, C_CONSUMER_SOURCE_DIR, WORK_DIR, GENERATOR, CXX_COMPILER, C_COMPILER,
# PYTHON and PYTHON_INSTALL_DIR (PYTHON empty: no Python module), and SAN_FLAGS (empty unless a
# sanitizer build).
foreach(var PBGI_BUILD_DIR CONSUMER_SOURCE_DIR COMPONENTS_SOURCE_DIR C_CONSUMER_SOURCE_DIR
        WORK_DIR GENERATOR CXX_COMPILER C_COMPILER)
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
# The core's package files must not look for what only the scene component and the command
# need: pbgiTargets.cmake as a whole, pbgiConfig.cmake up to its components (comments aside).
foreach(f pbgiConfig.cmake pbgiTargets.cmake)
  file(GLOB found "${WORK_DIR}/prefix/lib*/cmake/pbgi/${f}")
  if(NOT found)
    message(FATAL_ERROR "install_consumer: ${f} was not installed")
  endif()
  file(STRINGS "${found}" lines)
  set(text "")
  foreach(line IN LISTS lines)
    if(line MATCHES "^foreach\\(_pbgi_component")
      break()
    endif()
    if(NOT line MATCHES "^#")
      string(APPEND text "${line}\n")
    endif()
  endforeach()
  string(TOLOWER "${text}" text)
  foreach(dep embree assimp openexr stb)
    string(FIND "${text}" "${dep}" at)
    if(NOT at EQUAL -1)
      message(FATAL_ERROR "install_consumer: the core's ${f} mentions ${dep}")
    endif()
  endforeach()
endforeach()
set(san_args "")
if(SAN_FLAGS)
  set(san_args "-DCMAKE_CXX_FLAGS=${SAN_FLAGS}" "-DCMAKE_EXE_LINKER_FLAGS=${SAN_FLAGS}")
endif()
# Configured as on a machine without Embree, Assimp or OpenEXR: find_package of them fails.
step("configure consumer" ${CMAKE_COMMAND} -S "${CONSUMER_SOURCE_DIR}" -B "${WORK_DIR}/build"
     -G "${GENERATOR}" -DCMAKE_BUILD_TYPE=Release "-DCMAKE_CXX_COMPILER=${CXX_COMPILER}"
     "-DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix" -DCMAKE_DISABLE_FIND_PACKAGE_embree=TRUE
     -DCMAKE_DISABLE_FIND_PACKAGE_assimp=TRUE -DCMAKE_DISABLE_FIND_PACKAGE_OpenEXR=TRUE
     ${san_args})
step("build consumer" ${CMAKE_COMMAND} --build "${WORK_DIR}/build")
file(MAKE_DIRECTORY "${WORK_DIR}/run")
step("run consumer" "${WORK_DIR}/build/pbgi_consumer" "${WORK_DIR}/run")
if(NOT step_output MATCHES "consumer: ok")
  message(FATAL_ERROR "install_consumer: unexpected output: ${step_output}")
endif()
message(STATUS "${step_output}")
# A C-only project links the C API's shared library.
set(c_san_args "")
if(SAN_FLAGS)
  set(c_san_args "-DCMAKE_C_FLAGS=${SAN_FLAGS}" "-DCMAKE_EXE_LINKER_FLAGS=${SAN_FLAGS}")
endif()
step("configure C consumer" ${CMAKE_COMMAND} -S "${C_CONSUMER_SOURCE_DIR}" -B "${WORK_DIR}/c"
     -G "${GENERATOR}" -DCMAKE_BUILD_TYPE=Release "-DCMAKE_C_COMPILER=${C_COMPILER}"
     "-DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix" ${c_san_args})
step("build C consumer" ${CMAKE_COMMAND} --build "${WORK_DIR}/c")
step("run C consumer" "${WORK_DIR}/c/pbgi_c_consumer" "${WORK_DIR}/run")
if(NOT step_output MATCHES "c consumer: ok")
  message(FATAL_ERROR "install_consumer: unexpected output: ${step_output}")
endif()
message(STATUS "${step_output}")
# The installed Python package imports from the prefix and shades (not under a sanitizer: the
# interpreter would need the sanitizer's runtime preloaded; tests/python does that).
if(PYTHON AND NOT SAN_FLAGS)
  set(py_dir "${WORK_DIR}/prefix/${PYTHON_INSTALL_DIR}")
  if(NOT EXISTS "${py_dir}/pbgi/__init__.py")
    message(FATAL_ERROR "install_consumer: the Python package is not in ${py_dir}")
  endif()
  file(WRITE "${WORK_DIR}/use_pbgi.py" [=[
import sys, numpy as np, pbgi
assert pbgi.__file__.startswith(sys.argv[1]), pbgi.__file__
u = (np.arange(100) + 0.5) / 100 - 0.5
x, y = np.meshgrid(u, u)
p = np.stack([x.ravel(), y.ravel(), np.ones(x.size)], axis=1)
pbgi.build(sys.argv[2], p, np.tile([0, 0, -1.0], (len(p), 1)), np.full(len(p), 0.01 / np.pi**0.5))
out = pbgi.open(sys.argv[2]).shade([[0, 0, 0]], [[0, 0, 1]], mode="occlusion")
assert abs(out.occlusion[0] - 0.23946) < 0.03 * 0.23946, out.occlusion
print("python consumer: ok", pbgi.__version__, out.occlusion[0])
]=])
  step("import the installed Python module" ${CMAKE_COMMAND} -E env "PYTHONPATH=${py_dir}"
       "${PYTHON}" "${WORK_DIR}/use_pbgi.py" "${py_dir}" "${WORK_DIR}/run/py.pbgi")
  if(NOT step_output MATCHES "python consumer: ok")
    message(FATAL_ERROR "install_consumer: unexpected output: ${step_output}")
  endif()
  message(STATUS "${step_output}")
endif()
# The optional components resolve too (configure only).
step("configure components" ${CMAKE_COMMAND} -S "${COMPONENTS_SOURCE_DIR}"
     -B "${WORK_DIR}/components" -G "${GENERATOR}" "-DCMAKE_CXX_COMPILER=${CXX_COMPILER}"
     "-DCMAKE_PREFIX_PATH=${WORK_DIR}/prefix")
file(REMOVE_RECURSE "${WORK_DIR}")
