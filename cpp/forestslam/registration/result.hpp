// What every registration method returns, and planar-pose helpers shared by them.
#pragma once

#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "forestslam/common/types.hpp"

namespace forestslam::registration {

// T_target_source maps source-frame points into the target frame.
// covariance: 6x6 over the left perturbation (tx, ty, tz, rx, ry, rz) of T_target_source;
// planar methods fill the x, y, yaw block (indices 0, 1, 5) and leave z/roll/pitch at a large
// variance so that consumers can tell which directions were observed.
struct RegistrationResult {
    Pose3 T_target_source = Pose3::Identity();
    Matrix6d covariance = Matrix6d::Identity();
    bool converged = false;
    bool degenerate = true;
    int inliers = 0;  // matched pairs / ICP correspondences used at the end
    int iterations = 0;
    double rmse = 0.0;  // residual RMS of the inliers at the end (metres)
};

// Large variance for unobserved directions of planar results.
constexpr double kUnobservedVariance = 1e6;

// Planar pose helpers: (x, y, yaw) <-> Isometry3d (rotation about z only).
Pose3 planarToPose(double x, double y, double yaw);
Eigen::Vector3d poseToPlanar(const Pose3 &T);

// Rotation-vector exponential for small pose increments (left perturbation).
Pose3 expSE3(const Vector6d &delta);

}  // namespace forestslam::registration
