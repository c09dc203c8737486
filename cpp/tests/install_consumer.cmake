# ctest: install this build into a scratch prefix, then configure, build and run the consumer
# project against it with find_package(forestslam), and run the installed program.
set(prefix ${WORK}/prefix)
file(REMOVE_RECURSE ${WORK})
foreach(step
    "${CMAKE_COMMAND};--install;${BUILD};--component;forestslam_cpp;--prefix;${prefix}"
    "${CMAKE_COMMAND};-S;${SOURCE};-B;${WORK}/build;-DCMAKE_PREFIX_PATH=${prefix};-DCMAKE_BUILD_TYPE=Release"
    "${CMAKE_COMMAND};--build;${WORK}/build"
    "${WORK}/build/consumer"
    "${prefix}/${BINDIR}/forestslam_odometry;--help")
  execute_process(COMMAND ${step} RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "${step} failed (${rc}):\n${out}\n${err}")
  endif()
  message(STATUS "${out}")
endforeach()
if(NOT EXISTS ${prefix}/${DATADIR}/forestslam/sensors/vlp16.yaml)
  message(FATAL_ERROR "the sensor profiles were not installed")
endif()
