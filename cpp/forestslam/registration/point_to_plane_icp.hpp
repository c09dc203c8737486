// Point-to-plane ICP over 6 DoF (Gauss-Newton, Huber weights) against a target with normals.
// The target (KD-tree + normals from its own neighbourhoods) is built once and reused, so a
// local map serves many scans; each normal is computed the first time a query needs it. The k-d
// tree is our own (exact, double precision, gated queries).
#pragma once

#include <memory>

#include "forestslam/registration/result.hpp"

namespace forestslam::registration {

class PlaneTarget {
  public:
    // points (M,3), non-finite rows dropped. Normals from the normal_k nearest neighbours (PCA);
    // points whose neighbourhood is not planar enough (or too small) get no normal and are skipped.
    explicit PlaneTarget(const Eigen::Ref<const Points3> &points, int normal_k = 10);
    ~PlaneTarget();
    PlaneTarget(PlaneTarget &&) noexcept;
    PlaneTarget &operator=(PlaneTarget &&) noexcept;

    const Points3 &points() const;
    // (M,3), NaN rows where no normal. Normals are computed on first use (all of them here).
    const Points3 &normals() const;
    // The normal of one row (NaN where none), computed on first use and kept; safe to call
    // from several threads at once. std::out_of_range outside [0, size()).
    Eigen::Vector3d normal(int row) const;
    Eigen::Index size() const;
    // Index and squared distance of the nearest target point (-1 if the target is empty).
    int nearest(const Eigen::Vector3d &query, double &squared_distance) const;
    // The same within max_distance_m only (-1 if none): faster, the search is pruned.
    int nearest(const Eigen::Vector3d &query, double max_distance_m,
                double &squared_distance) const;

  private:
    struct Impl;
    std::unique_ptr<Impl> impl_;
};

struct IcpConfig {
    // Measured on vlp16-loop / vlp16-rough (200 scans, odometry_bench): 30 iterations, 5 to
    // shrink, tolerances 1e-4 m / 1e-5 rad gave the same ATE (0.012 / 0.027 m against 0.014 /
    // 0.027 m) for 45 % more ICP CPU (1.9 / 2.6 ms against 1.3 / 1.8 ms per scan).
    int max_iterations = 12;
    double max_correspondence_m = 1.0;    // first iterations
    double final_correspondence_m = 0.3;  // shrinks geometrically towards this
    int shrink_iterations = 3;            // ... reaching it after this many iterations
    // While the correspondence distance still shrinks, only every coarse_stride-th source point
    // is used (1: all): those iterations only bring the pose into the basin, and their wide
    // searches are the costliest. Every iteration at the final distance, the one the result
    // and its covariance come from included, uses all points. 3 saves ~0.25 ms of ~2.2 ms per
    // VLP-16 scan; on 9 sequences (with 1 m SLAM keyframes) RPE was within the run-to-run
    // spread but higher on average (issue 18), so 1 stays the default.
    int coarse_stride = 1;
    double huber_m = 0.05;  // robust kernel width on point-to-plane residuals
    double translation_tolerance_m = 5e-4;
    double rotation_tolerance_rad = 5e-5;
    int min_correspondences = 20;
    // A direction is degenerate when its share of constraint per correspondence is below this
    // (rotations scaled by degeneracy_length_m so that they are compared as metres of arc).
    double degeneracy_threshold = 2e-3;
    double degeneracy_length_m = 10.0;
    int normal_k = 10;  // PlaneTarget normals from this many nearest neighbours
};

// The residual of one correspondence and its Jacobian with respect to the left perturbation
// (tx, ty, tz, rx, ry, rz) of T: r = n . (T p - q). Exposed for derivative tests.
double pointToPlaneResidual(const Pose3 &T, const Eigen::Vector3d &p, const Eigen::Vector3d &q,
                            const Eigen::Vector3d &n, Eigen::Matrix<double, 1, 6> *jacobian);

// Register source (N,3) onto target from T_init. prior_information (6x6, optional, may be zero)
// pulls the pose towards T_prior (e.g. the constant-velocity prediction) in the same left
// perturbation coordinates; it regularises directions the geometry does not constrain.
// std::invalid_argument when T_init, T_prior or prior_information is not finite.
RegistrationResult icpPointToPlane(const PlaneTarget &target,
                                   const Eigen::Ref<const Points3> &source, const Pose3 &T_init,
                                   const IcpConfig &config = {},
                                   const Matrix6d &prior_information = Matrix6d::Zero(),
                                   const Pose3 &T_prior = Pose3::Identity());

}  // namespace forestslam::registration
