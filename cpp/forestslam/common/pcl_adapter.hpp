// Internal adapter between the Eigen API and PCL. Include only from .cpp files: PCL types
// never appear in public headers.
#pragma once

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include "forestslam/common/types.hpp"

namespace forestslam::detail {

pcl::PointCloud<pcl::PointXYZ>::Ptr toPcl(const Eigen::Ref<const Points3> &points);
Points3 fromPcl(const pcl::PointCloud<pcl::PointXYZ> &cloud);

}  // namespace forestslam::detail
