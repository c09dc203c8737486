forestslam_add_test(ray_primitives sim)
forestslam_add_test(forest_scene sim)
forestslam_add_test(scan_synthesis sim)
