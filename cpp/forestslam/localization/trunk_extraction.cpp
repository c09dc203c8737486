#include "forestslam/localization/trunk_extraction.hpp"

#include <pcl/filters/voxel_grid.h>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/search/kdtree.h>
#include <pcl/segmentation/extract_clusters.h>

#include <algorithm>

#include "forestslam/common/pcl_adapter.hpp"

namespace forestslam {

Trunks extractTrunks(const Eigen::Ref<const Points3> &cloud_in, const TrunkExtractionConfig &cfg) {
    Trunks out;
    out.xy.resize(0, 2);
    const Points3 finite = finiteRows(cloud_in);
    if (finite.rows() == 0) return out;
    auto cloud = detail::toPcl(finite);
    if (cfg.voxel_m > 0) {
        // VoxelGrid overflows its 32-bit index on huge extents at a tiny leaf: it then warns and
        // returns the input, which is still correct, only slower.
        pcl::VoxelGrid<pcl::PointXYZ> voxel;
        voxel.setInputCloud(cloud);
        voxel.setLeafSize(cfg.voxel_m, cfg.voxel_m, cfg.voxel_m);
        auto down = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
        voxel.filter(*down);
        if (!down->empty()) cloud = down;
    }

    // Points with a neighbour about t_h above them.
    pcl::KdTreeFLANN<pcl::PointXYZ> kdtree;
    kdtree.setInputCloud(cloud);
    auto kept = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
    std::vector<int> nn(1);
    std::vector<float> nd(1);
    for (const auto &p : cloud->points) {
        pcl::PointXYZ above = p;
        above.z += static_cast<float>(cfg.height_offset_m);
        if (kdtree.radiusSearch(above, cfg.neighbour_radius_m, nn, nd, 1) > 0) kept->push_back(p);
    }
    if (kept->empty()) return out;

    auto tree = std::make_shared<pcl::search::KdTree<pcl::PointXYZ>>();
    tree->setInputCloud(kept);
    std::vector<pcl::PointIndices> clusters;
    pcl::EuclideanClusterExtraction<pcl::PointXYZ> ec;
    ec.setClusterTolerance(cfg.cluster_tolerance_m);
    ec.setMinClusterSize(std::max(1, cfg.min_cluster_points));
    ec.setMaxClusterSize(std::max(1, cfg.max_cluster_points));
    ec.setSearchMethod(tree);
    ec.setInputCloud(kept);
    ec.extract(clusters);

    out.xy.resize(clusters.size(), 2);
    out.z_min.resize(clusters.size());
    out.z_max.resize(clusters.size());
    for (size_t c = 0; c < clusters.size(); ++c) {
        Eigen::Vector2d sum = Eigen::Vector2d::Zero();
        double zmin = std::numeric_limits<double>::max(), zmax = std::numeric_limits<double>::lowest();
        for (int i : clusters[c].indices) {
            const auto &p = (*kept)[i];
            sum += Eigen::Vector2d(p.x, p.y);
            zmin = std::min(zmin, double(p.z));
            zmax = std::max(zmax, double(p.z));
        }
        out.xy.row(c) = (sum / double(clusters[c].indices.size())).transpose();
        out.z_min[c] = zmin;
        out.z_max[c] = zmax;
        out.sizes.push_back(static_cast<int>(clusters[c].indices.size()));
    }
    return out;
}

}  // namespace forestslam
