# forestslam_add_library(<concern> SOURCES ... [DEPENDS ...]): one small library per concern,
# exported as forestslam::<concern> (in the build tree and in the installed package).
function(forestslam_add_library concern)
  cmake_parse_arguments(ARG "" "" "SOURCES;DEPENDS" ${ARGN})
  set(target forestslam_${concern})
  add_library(${target} STATIC ${ARG_SOURCES})
  target_include_directories(${target} PUBLIC $<BUILD_INTERFACE:${PROJECT_SOURCE_DIR}>
                                               $<INSTALL_INTERFACE:${CMAKE_INSTALL_INCLUDEDIR}>)
  target_link_libraries(${target} PUBLIC Eigen3::Eigen ${ARG_DEPENDS})
  target_compile_options(${target} PRIVATE -Wall -Wextra)
  set_target_properties(${target} PROPERTIES EXPORT_NAME ${concern})
  add_library(forestslam::${concern} ALIAS ${target})
  set_property(GLOBAL APPEND PROPERTY FORESTSLAM_LIBRARIES ${target})
endfunction()
