// Trunk positions from a map point cloud (Li et al., Algorithm 1): keep points that have a
// neighbour about height_offset_m above them (vertical structures), cluster them, and return
// the mean XY of each large enough cluster.
#pragma once

#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam {

struct TrunkExtractionConfig {
    double voxel_m = 0.05;              // downsampling before the search; 0 = off
    double height_offset_m = 1.0;       // t_h: look for a neighbour this far above
    double neighbour_radius_m = 0.15;   // radius around the point t_h above
    double cluster_tolerance_m = 0.3;   // Euclidean clustering distance
    int min_cluster_points = 15;        // smaller clusters are dropped
    int max_cluster_points = 1000000;
};

struct Trunks {
    Points2 xy;                  // (K,2) mean XY per trunk cluster
    std::vector<int> sizes;      // points per cluster
    Eigen::VectorXd z_min, z_max;  // vertical extent of each cluster
};

// cloud (N,3); non-finite rows ignored. Empty input gives an empty result.
Trunks extractTrunks(const Eigen::Ref<const Points3> &cloud, const TrunkExtractionConfig &config = {});

}  // namespace forestslam
