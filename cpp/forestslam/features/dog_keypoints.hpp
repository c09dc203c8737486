// Real features of Shao et al. (2020): 3D difference-of-Gaussians keypoints, evenly spread.
#pragma once

#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam::features {

struct DogKeypointsConfig {
    double voxel_m = 0.08;  // downsampling before smoothing (bounds the cost)
    // Outlier removal: points with fewer neighbours than this within 3 sigma_small (after
    // voxelisation) are never keypoints (isolated returns give the strongest responses).
    int outlier_neighbours = 8;
    double sigma_small_m = 0.15;  // Gaussian scales of the two smoothed copies
    double sigma_large_m = 0.30;
    int min_neighbours = 6;     // points with fewer neighbours at the large scale: skipped
    double nms_radius_m = 0.6;  // non-maximum suppression of the response
    double bucket_m = 3.0;      // horizontal buckets that spread keypoints evenly
    int max_keypoints = 200;
};

// Keypoints are original (filtered) cloud points, so a map surface passes through them.
struct DogKeypoints {
    Points3 points;            // (K,3)
    Eigen::VectorXd response;  // (K,) |smoothed_small - smoothed_large| in metres
};

// Empty or all-NaN input gives an empty result.
DogKeypoints detectDogKeypoints(const Eigen::Ref<const Points3> &points,
                                const DogKeypointsConfig &config = {});

}  // namespace forestslam::features
