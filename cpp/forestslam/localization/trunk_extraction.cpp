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

namespace {

using Cloud = pcl::PointCloud<pcl::PointXYZ>;

// The cloud on a voxel grid (voxel_m <= 0: as is). VoxelGrid overflows its 32-bit index on huge
// extents at a tiny leaf: it then warns and returns the input, which is still correct, only
// slower.
Cloud::Ptr downsample(Cloud::Ptr cloud, double voxel_m) {
    if (voxel_m <= 0) return cloud;
    pcl::VoxelGrid<pcl::PointXYZ> voxel;
    voxel.setInputCloud(cloud);
    voxel.setLeafSize(voxel_m, voxel_m, voxel_m);
    auto down = std::make_shared<Cloud>();
    voxel.filter(*down);
    return down->empty() ? cloud : down;
}

// Local ground: the lowest point of each cell (and its 8 neighbours, against empty cells).
class LocalGround {
  public:
    LocalGround(const Cloud &cloud, double cell_m) : cell_(std::max(cell_m, 0.1)) {
        for (const auto &p : cloud.points) {
            auto [it, inserted] = lowest_.emplace(key(p.x, p.y), p.z);
            if (!inserted) it->second = std::min(it->second, p.z);
        }
    }
    float at(double x, double y) const {
        const auto [cx, cy] = key(x, y);
        float z = std::numeric_limits<float>::max();
        for (int64_t dx = -1; dx <= 1; ++dx)
            for (int64_t dy = -1; dy <= 1; ++dy) {
                const auto it = lowest_.find({cx + dx, cy + dy});
                if (it != lowest_.end()) z = std::min(z, it->second);
            }
        return z;
    }

  private:
    std::pair<int64_t, int64_t> key(double x, double y) const {
        return std::make_pair(static_cast<int64_t>(std::floor(x / cell_)),
                              static_cast<int64_t>(std::floor(y / cell_)));
    }
    double cell_;
    std::map<std::pair<int64_t, int64_t>, float> lowest_;
};

// Points in the band above the local ground with a neighbour about t_h above them.
Cloud::Ptr verticalStructure(const Cloud::Ptr &cloud, const TrunkExtractionConfig &cfg) {
    const LocalGround ground(*cloud, cfg.ground_cell_m);
    pcl::KdTreeFLANN<pcl::PointXYZ> kdtree;
    kdtree.setInputCloud(cloud);
    auto kept = std::make_shared<Cloud>();
    std::vector<int> nn(1);
    std::vector<float> nd(1);
    for (const auto &p : cloud->points) {
        const double h = p.z - ground.at(p.x, p.y);
        if (h < cfg.band_min_m || h > cfg.band_max_m) continue;
        pcl::PointXYZ above = p;
        above.z += static_cast<float>(cfg.height_offset_m);
        if (kdtree.radiusSearch(above, cfg.neighbour_radius_m, nn, nd, 1) > 0) kept->push_back(p);
    }
    return kept;
}

std::vector<pcl::PointIndices> euclideanClusters(const Cloud::Ptr &kept,
                                                 const TrunkExtractionConfig &cfg) {
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
    return clusters;
}

// The cluster's mean XY appended to centres and its extent to out when it looks like a stem
// (tall and narrow; shrubs and branch tangles are not).
void addIfStem(const Cloud &kept, const pcl::PointIndices &cluster,
               const TrunkExtractionConfig &cfg, std::vector<Eigen::Vector2d> &centres,
               Trunks &out) {
    Eigen::Vector2d sum = Eigen::Vector2d::Zero();
    double zmin = std::numeric_limits<double>::max(), zmax = std::numeric_limits<double>::lowest();
    for (int i : cluster.indices) {
        const auto &p = kept[i];
        sum += Eigen::Vector2d(p.x, p.y);
        zmin = std::min(zmin, double(p.z));
        zmax = std::max(zmax, double(p.z));
    }
    const Eigen::Vector2d mean = sum / double(cluster.indices.size());
    double spread = 0;
    for (int i : cluster.indices)
        spread = std::max(spread, (Eigen::Vector2d(kept[i].x, kept[i].y) - mean).norm());
    if (zmax - zmin < cfg.min_cluster_height_m || spread > cfg.max_cluster_radius_m) return;
    centres.push_back(mean);
    out.z_min.conservativeResize(out.z_min.size() + 1);
    out.z_max.conservativeResize(out.z_max.size() + 1);
    out.z_min[out.z_min.size() - 1] = zmin;
    out.z_max[out.z_max.size() - 1] = zmax;
    out.sizes.push_back(static_cast<int>(cluster.indices.size()));
}

}  // namespace

Trunks extractTrunks(const Eigen::Ref<const Points3> &cloud_in, const TrunkExtractionConfig &cfg) {
    Trunks out;
    out.xy.resize(0, 2);
    const Points3 finite = finiteRows(cloud_in);
    if (finite.rows() == 0) return out;
    const Cloud::Ptr cloud = downsample(detail::toPcl(finite), cfg.voxel_m);
    const Cloud::Ptr kept = verticalStructure(cloud, cfg);
    if (kept->empty()) return out;
    std::vector<Eigen::Vector2d> centres;
    for (const auto &cluster : euclideanClusters(kept, cfg))
        addIfStem(*kept, cluster, cfg, centres, out);
    out.xy.resize(centres.size(), 2);
    for (size_t k = 0; k < centres.size(); ++k) out.xy.row(k) = centres[k].transpose();
    return out;
}

}  // namespace forestslam::localization
