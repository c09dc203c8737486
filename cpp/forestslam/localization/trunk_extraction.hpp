// Trunk positions from a map point cloud (Li et al., Algorithm 1): keep points that have a
// neighbour about height_offset_m above them (vertical structures), cluster them, and return
// the mean XY of each large enough cluster. Only points in a band above the local ground (the
// lowest point of each ground cell) are searched, so crowns and branches do not count, and
// clusters must look like a stem (tall and narrow enough).
#pragma once

#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam::localization {

struct TrunkExtractionConfig {
    double voxel_m = 0.05;             // downsampling before the search; 0 = off
    double height_offset_m = 1.0;      // t_h: look for a neighbour this far above
    double neighbour_radius_m = 0.15;  // radius around the point t_h above
    double cluster_tolerance_m = 0.3;  // Euclidean clustering distance
    int min_cluster_points = 15;       // smaller clusters are dropped
    int max_cluster_points = 1000000;
    double ground_cell_m = 2.0;  // local ground: lowest point per cell of this size
    double band_min_m = 0.3;     // search band above the local ground
    double band_max_m = 3.0;
    double min_cluster_height_m = 1.0;  // vertical extent of a stem cluster
    double max_cluster_radius_m = 1.0;  // horizontal spread (max distance to the mean XY)
};

struct Trunks {
    Points2 xy;                    // (K,2) mean XY per trunk cluster
    std::vector<int> sizes;        // points per cluster
    Eigen::VectorXd z_min, z_max;  // vertical extent of each cluster
};

// cloud (N,3); non-finite rows ignored. Empty input gives an empty result.
Trunks extractTrunks(const Eigen::Ref<const Points3> &cloud,
                     const TrunkExtractionConfig &config = {});

}  // namespace forestslam::localization
