forestslam_add_test(types common)
forestslam_add_test(pcl_adapter common)
forestslam_add_test(voxel_key common)
forestslam_add_test(kdtree common)
