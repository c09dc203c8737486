// Baseline of the paper's Table 2: FPFH features + RANSAC (PCL SampleConsensusPrerejective),
// refined by point-to-plane ICP, on clouds voxelised at 0.25 m.
#pragma once

#include "forestslam/registration/point_to_plane_icp.hpp"

namespace forestslam::registration {

struct FpfhConfig {
    double voxel_m = 0.25;
    double normal_radius_m = 0.75;   // 3 voxels
    double feature_radius_m = 1.25;  // 5 voxels
    int ransac_iterations = 20000;
    int correspondence_randomness = 3;  // k nearest features drawn per sample
    double similarity_threshold = 0.9;  // edge-length agreement of the 3-point sample
    double inlier_distance_m = 0.5;     // max distance of an inlier after alignment
    double inlier_fraction = 0.25;      // accept a hypothesis above this share of inliers
    unsigned int seed = 42;             // RANSAC is seeded: same input, same output
    IcpConfig icp{};
};

// T_target_source of source onto target (both (N,3)). inliers: RANSAC inliers of the global step
// (ICP correspondences are in rmse/converged); degenerate when RANSAC finds no hypothesis or ICP
// is ill-conditioned. On RANSAC failure the ICP starts from T_init (std::invalid_argument when it
// is not finite).
RegistrationResult registerFpfh(const Eigen::Ref<const Points3> &source,
                                const Eigen::Ref<const Points3> &target,
                                const Pose3 &T_init = Pose3::Identity(),
                                const FpfhConfig &config = {});

// Voxel-grid centroid downsampling (PCL VoxelGrid), non-finite rows dropped; voxel_m <= 0
// returns the finite rows unchanged.
Points3 voxelCentroids(const Eigen::Ref<const Points3> &points, double voxel_m);

}  // namespace forestslam::registration
