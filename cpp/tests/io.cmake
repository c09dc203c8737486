forestslam_add_test(lzf io)
forestslam_add_test(point_mask io)

# Cross-check against PCL's own LZF (what writes binary_compressed PCD files) when pcl_io exists.
find_library(FORESTSLAM_PCL_IO_LIBRARY NAMES pcl_io HINTS ${PCL_LIBRARY_DIRS})
if(FORESTSLAM_PCL_IO_LIBRARY)
  forestslam_add_test(lzf_pcl io)
  target_link_libraries(test_lzf_pcl PRIVATE ${FORESTSLAM_PCL_IO_LIBRARY})
endif()
