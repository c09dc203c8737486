// Shape-to-shape registration of tree stems (Gupta et al. 2023, Eq. 3) over x, y, yaw.
// Each stem is a Gaussian (mean, covariance) of its points; the cost of matched pairs is
//   f = -sum_i exp(-1/2 mu_i^T Sigma_i^-1 mu_i),  mu_i = R mu_S + t - mu_T,
//   Sigma_i = R Sigma_S R^T + Sigma_T,
// evaluated on the XY marginals (rotation about z only), minimised with Ceres (L-BFGS, autodiff).
// A consensus step over pairs of matches picks the inlier set first, so wrong pairs cannot pull.
#pragma once

#include <utility>
#include <vector>

#include "forestslam/registration/result.hpp"

namespace forestslam::registration {

// Stem Gaussians: means (K,3), covariances (K,9) row-major 3x3 each.
using Covariances = Eigen::Matrix<double, Eigen::Dynamic, 9, Eigen::RowMajor>;

struct ShapeRegistrationConfig {
    double min_sigma_m = 0.05;           // added (squared) to each Sigma_i diagonal: noise floor
    double consensus_tolerance_m = 0.3;  // pair-distance agreement for a 2-pair hypothesis
    double inlier_threshold_m = 0.5;     // residual of a pair under a hypothesis to count as inlier
    int max_consensus_pairs = 2000;      // cap on hypotheses tried (all pairs of matches if fewer)
    int max_iterations = 50;             // Ceres L-BFGS iterations
    int min_inliers_not_degenerate = 3;  // <= 2 consistent stems -> degenerate flag
};

// Cost of Eq. 3 and its gradient for one pose (x, y, yaw): exposed for tests and diagnostics.
double shapeCost(const double pose[3], const Eigen::Ref<const Points3> &source_means,
                 const Eigen::Ref<const Covariances> &source_covs,
                 const Eigen::Ref<const Points3> &target_means,
                 const Eigen::Ref<const Covariances> &target_covs,
                 const std::vector<std::pair<int, int>> &pairs, double min_sigma_m,
                 double gradient[3]);

// pairs (i source, j target) from matchTrees. Result T_target_source is planar; covariance holds
// the linearised (Gauss-Newton) x, y, yaw covariance in indices 0, 1, 5; inliers = consistent
// pairs. Pairs with a non-finite stem are skipped. std::invalid_argument when a pair index is
// out of range or a side has not one covariance row per mean (shapeCost, consensusPairs too).
RegistrationResult registerShapes(const Eigen::Ref<const Points3> &source_means,
                                  const Eigen::Ref<const Covariances> &source_covs,
                                  const Eigen::Ref<const Points3> &target_means,
                                  const Eigen::Ref<const Covariances> &target_covs,
                                  const std::vector<std::pair<int, int>> &pairs,
                                  const Pose3 &T_init, const ShapeRegistrationConfig &config = {});

// Consensus over pairs of matches: the planar pose with most pairs within inlier_threshold_m
// (the initial pose is one hypothesis). Returns (pose, inlier pair indices).
std::pair<Pose3, std::vector<int>> consensusPairs(const Eigen::Ref<const Points3> &source,
                                                  const Eigen::Ref<const Points3> &target,
                                                  const std::vector<std::pair<int, int>> &pairs,
                                                  const Pose3 &T_init,
                                                  const ShapeRegistrationConfig &config);

}  // namespace forestslam::registration
