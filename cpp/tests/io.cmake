forestslam_add_test(lzf io)
