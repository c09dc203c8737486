// 3D-NDT (PCL NormalDistributionsTransform) between consecutive frames: the initial pose of
// the stem-centre LM in the MLS-to-TLS pipeline (Shao et al. 2020, Sec. 3.3).
#pragma once

#include "forestslam/common/types.hpp"

namespace forestslam::registration {

struct NdtConfig {
    double voxel_m = 0.3;       // both clouds are voxel-downsampled first
    double resolution_m = 1.0;  // NDT cell size
    double step_size_m = 0.1;   // More-Thuente line search maximum step
    double epsilon = 1e-3;      // transformation change that ends the iteration
    int max_iterations = 35;
    double max_range_m = 40.0;  // points farther from the frame origin are ignored
    int min_points = 50;        // fewer points after filtering: not converged
};

struct NdtResult {
    Pose3 T_target_source = Pose3::Identity();
    bool converged = false;
    int iterations = 0;
    double fitness = 0.0;  // PCL fitness score: mean squared nearest distance (m^2)
};

// Align source (N,3) onto target (M,3) starting from T_initial (T_target_source). On too few
// points or non-convergence T_target_source is the initial guess and converged is false.
// Throws std::invalid_argument when T_initial is not finite.
NdtResult registerNdt(const Eigen::Ref<const Points3> &target,
                      const Eigen::Ref<const Points3> &source,
                      const Pose3 &T_initial = Pose3::Identity(), const NdtConfig &config = {});

}  // namespace forestslam::registration
