# MLS-to-TLS engineer's units (features, stem-centre LM, NDT).
forestslam_add_test(voxel_grid features)
forestslam_add_test(dog_keypoints features)
forestslam_add_test(virtual_features features)
if(TARGET forestslam_registration)
  forestslam_add_test(stem_centre_lm registration)
  forestslam_add_test(ndt registration)
endif()
