forestslam_add_test(motion_model odometry)
forestslam_add_test(local_map odometry)
forestslam_add_test(tree_odometry odometry)
forestslam_add_test(sensor_profile odometry)
target_compile_definitions(test_sensor_profile PRIVATE
  FORESTSLAM_PROFILES="${PROJECT_SOURCE_DIR}/../python/forestslam/sensors/profiles")
