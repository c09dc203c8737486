#include "forestslam/common/pcl_adapter.hpp"

namespace forestslam::detail {

pcl::PointCloud<pcl::PointXYZ>::Ptr toPcl(const Eigen::Ref<const Points3> &points) {
    auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
    cloud->resize(points.rows());
    for (Eigen::Index i = 0; i < points.rows(); ++i) {
        (*cloud)[i].getVector3fMap() = points.row(i).transpose().cast<float>();
    }
    cloud->width = static_cast<uint32_t>(points.rows());
    cloud->height = 1;
    cloud->is_dense = true;
    return cloud;
}

Points3 fromPcl(const pcl::PointCloud<pcl::PointXYZ> &cloud) {
    Points3 out(cloud.size(), 3);
    for (size_t i = 0; i < cloud.size(); ++i) {
        out.row(i) = cloud[i].getVector3fMap().cast<double>().transpose();
    }
    return out;
}

}  // namespace forestslam::detail
