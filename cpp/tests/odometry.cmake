forestslam_add_test(motion_model odometry)
forestslam_add_test(local_map odometry)
forestslam_add_test(tree_odometry odometry)
forestslam_add_test(sensor_profile odometry)
target_compile_definitions(test_sensor_profile PRIVATE
  FORESTSLAM_PROFILES="${PROJECT_SOURCE_DIR}/../python/forestslam/sensors/profiles")

# The installed CMake package works for an outside program.
add_test(NAME InstallConsumer
         COMMAND ${CMAKE_COMMAND} -DBUILD=${PROJECT_BINARY_DIR}
                 -DSOURCE=${CMAKE_CURRENT_SOURCE_DIR}/consumer
                 -DWORK=${CMAKE_CURRENT_BINARY_DIR}/install_consumer
                 -DBINDIR=${CMAKE_INSTALL_BINDIR} -DDATADIR=${CMAKE_INSTALL_DATADIR}
                 -P ${CMAKE_CURRENT_SOURCE_DIR}/install_consumer.cmake)
