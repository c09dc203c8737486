#include "forestslam/localization/trunk_extraction.hpp"

#include <pcl/filters/voxel_grid.h>
#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/search/kdtree.h>
#include <pcl/segmentation/extract_clusters.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>

#include "forestslam/common/pcl_adapter.hpp"

namespace forestslam::localization {

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

    // Local ground: the lowest point of each cell (and its 8 neighbours, against empty cells).
    const double cell = std::max(cfg.ground_cell_m, 0.1);
    auto cellKey = [&](double x, double y) {
        return std::make_pair(static_cast<int64_t>(std::floor(x / cell)),
                              static_cast<int64_t>(std::floor(y / cell)));
    };
    std::map<std::pair<int64_t, int64_t>, float> lowest;
    for (const auto &p : cloud->points) {
        auto [it, inserted] = lowest.emplace(cellKey(p.x, p.y), p.z);
        if (!inserted) it->second = std::min(it->second, p.z);
    }
    auto groundAt = [&](double x, double y) {
        const auto [cx, cy] = cellKey(x, y);
        float z = std::numeric_limits<float>::max();
        for (int64_t dx = -1; dx <= 1; ++dx)
            for (int64_t dy = -1; dy <= 1; ++dy) {
                const auto it = lowest.find({cx + dx, cy + dy});
                if (it != lowest.end()) z = std::min(z, it->second);
            }
        return z;
    };

    // Points in the band with a neighbour about t_h above them.
    pcl::KdTreeFLANN<pcl::PointXYZ> kdtree;
    kdtree.setInputCloud(cloud);
    auto kept = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
    std::vector<int> nn(1);
    std::vector<float> nd(1);
    for (const auto &p : cloud->points) {
        const double h = p.z - groundAt(p.x, p.y);
        if (h < cfg.band_min_m || h > cfg.band_max_m) continue;
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

    std::vector<Eigen::Vector2d> centres;
    for (const auto &cluster : clusters) {
        Eigen::Vector2d sum = Eigen::Vector2d::Zero();
        double zmin = std::numeric_limits<double>::max(),
               zmax = std::numeric_limits<double>::lowest();
        for (int i : cluster.indices) {
            const auto &p = (*kept)[i];
            sum += Eigen::Vector2d(p.x, p.y);
            zmin = std::min(zmin, double(p.z));
            zmax = std::max(zmax, double(p.z));
        }
        const Eigen::Vector2d mean = sum / double(cluster.indices.size());
        double spread = 0;
        for (int i : cluster.indices)
            spread = std::max(spread, (Eigen::Vector2d((*kept)[i].x, (*kept)[i].y) - mean).norm());
        // A stem is tall and narrow; shrubs and branch tangles are not.
        if (zmax - zmin < cfg.min_cluster_height_m || spread > cfg.max_cluster_radius_m) continue;
        centres.push_back(mean);
        out.z_min.conservativeResize(out.z_min.size() + 1);
        out.z_max.conservativeResize(out.z_max.size() + 1);
        out.z_min[out.z_min.size() - 1] = zmin;
        out.z_max[out.z_max.size() - 1] = zmax;
        out.sizes.push_back(static_cast<int>(cluster.indices.size()));
    }
    out.xy.resize(centres.size(), 2);
    for (size_t k = 0; k < centres.size(); ++k) out.xy.row(k) = centres[k].transpose();
    return out;
}

}  // namespace forestslam::localization
