// Stem-centre Levenberg-Marquardt registration (Shao et al., ISPRS 2020, Sec. 3.3):
// virtual features (stem centres with radius) pair with the nearest target points around them at
// the same height, one per angular sector (residual d - r, d the horizontal distance in the
// target frame, whose z axis is taken as vertical: a levelled TLS / map frame; pairing all
// around the centre rather than only the nearest point removes the mirror minimum outside a
// fully scanned stem); real features (e.g. DoG keypoints) pair with the plane through their three
// nearest non-collinear target points (point-to-plane residual). 6 DoF, Ceres LM (all pairs of a
// round in one residual block with analytic Jacobians, left perturbation of the pose) with a
// robust Cauchy loss, correspondences renewed between solves. Works frame-to-frame and
// frame-to-map.
#pragma once

#include <memory>

#include "forestslam/registration/result.hpp"

namespace forestslam::registration {

struct StemCentreLmConfig {
    int max_rounds = 15;              // correspondence renewals
    int max_solver_iterations = 8;    // LM iterations per round (fixed pairs)
    double virtual_gate_m = 0.10;     // |d - r| gate for virtual-feature pairs
    int virtual_sectors = 12;         // at most one target point per sector around a centre
    double virtual_window_m = 0.15;   // ... taken within this height of the centre
    double virtual_max_gate_m = 0.5;  // cap of the coarse virtual gate (bounds the search)
    double real_gate_m = 0.50;        // max distance keypoint -> nearest target point
    double plane_gate_m = 0.25;       // max |point-to-plane| distance of a kept pair
    double min_triangle_ratio = 0.2;  // non-collinearity: 2*area / longest_edge^2
    double robust_scale_m = 0.05;     // Cauchy loss scale
    // Coarse to fine: the first round's gates and loss scale are coarse_gate_factor times the
    // above, shrinking by gate_decay per round down to 1x (tolerates a poorer initial guess).
    double coarse_gate_factor = 4.0;
    double gate_decay = 0.6;
    // Weight of one stem centre relative to one real feature, shared by the centre's pairs
    // (a centre is one observation however many target points it pairs with).
    double virtual_weight = 1.0;
    double converged_translation_m = 1e-4;  // stop when a round moves less than this ...
    double converged_rotation_rad = 1e-5;   // ... and rotates less than this
    int min_inliers = 12;                   // fewer pairs than this: not converged
    double degenerate_eigen_ratio = 1e-3;   // min/max eigenvalue of the normalised information
    // Motion during the sweep (continuous time; needs SweepTimes): 0 = rigid frame; k > 0
    // estimates, besides the pose at time 0, a polynomial of order k in the feature time tau
    // (seconds from the registration time, e.g. mid-sweep) of a 6-vector [t (3), w (3)]: the
    // feature at tau is moved by exp(w(tau)) about the sensor position plus t(tau) after the
    // pose (vibrating hand-held scanners: roll/pitch and height change within a sweep). Each
    // coefficient has a weak zero prior: its effect at tau = sweep_prior_tau_s has a standard
    // deviation of sweep_prior_m / sweep_prior_rad (only matters where the data are weak).
    int sweep_order = 0;
    double sweep_prior_tau_s = 0.05;
    double sweep_prior_m = 0.03;
    double sweep_prior_rad = 0.02;
};

// Per-feature times (seconds from the registration time) for the in-sweep motion.
struct SweepTimes {
    Eigen::VectorXd centres;  // (V,) one per virtual centre
    Eigen::VectorXd real;     // (R,) one per real feature
};

// RegistrationResult (T_target_source, 6x6 covariance over the left perturbation
// [tx, ty, tz, rx, ry, rz] from the Gauss-Newton information scaled by the residual variance,
// converged, degenerate, inliers, iterations = correspondence rounds, rmse over all pairs) plus
// the split by feature kind.
struct StemCentreLmResult : RegistrationResult {
    int virtual_inliers = 0;
    int real_inliers = 0;
    double virtual_rms_m = 0.0;  // RMS of d - r over virtual pairs at the solution (0 if none)
    double real_rms_m = 0.0;     // RMS point-to-plane distance over real pairs (0 if none)
    // In-sweep motion (sweep_order rows, row k-1 the coefficient of tau^k, columns [t, w] in
    // the target frame) about the sensor position T_target_source.translation(); empty when
    // rigid. A source point p at time tau lies at
    // exp(w(tau)) (T p - o) + o + t(tau), o = T translation, (t, w)(tau) = sum_k tau^k row_k.
    Eigen::MatrixXd sweep;
};

// Target surface: a KD-tree over a map or frame cloud, built once and reused for many frames.
class StemCentreTarget {
  public:
    explicit StemCentreTarget(const Eigen::Ref<const Points3> &points);
    ~StemCentreTarget();
    StemCentreTarget(const StemCentreTarget &) = delete;
    StemCentreTarget &operator=(const StemCentreTarget &) = delete;

    Eigen::Index size() const;
    const Points3 &points() const;

    struct Impl;
    const Impl &impl() const { return *impl_; }

  private:
    std::unique_ptr<Impl> impl_;
};

// The target points that can pair with each feature (gathered around where the feature was),
// kept between registrations of the same features onto the same target: the rigid LM of a
// frame, its fallbacks from other initial poses and its in-sweep LM then gather them about
// once instead of once per call. Reuse is exact (the same pairs as a fresh gather, see
// VirtualCandidates and RealCandidates): a registration with other features (after the
// usable-feature filter) or another target starts the cache afresh. Not thread-safe.
class StemCentreLmCache {
  public:
    StemCentreLmCache();
    ~StemCentreLmCache();
    StemCentreLmCache(const StemCentreLmCache &) = delete;
    StemCentreLmCache &operator=(const StemCentreLmCache &) = delete;

    struct Impl;
    Impl &impl() { return *impl_; }

  private:
    std::unique_ptr<Impl> impl_;
};

// Register source features onto the target. virtual_centres (V,3) with radii (V,), real
// points (R,3), both in the source frame. Either set may be empty; with too few pairs the
// result is flagged not converged / degenerate and T stays at the initial guess. times (one
// per feature) are needed when config.sweep_order > 0 (std::invalid_argument without them, or
// with other lengths) and ignored otherwise. std::invalid_argument too when radii and
// virtual_centres differ in length or T_initial is not finite. cache (optional): candidates
// shared with earlier registrations of the same features onto the same target (same result).
StemCentreLmResult registerStemCentreLm(
    const StemCentreTarget &target, const Eigen::Ref<const Points3> &virtual_centres,
    const Eigen::Ref<const Eigen::VectorXd> &radii, const Eigen::Ref<const Points3> &real_points,
    const Pose3 &T_initial, const StemCentreLmConfig &config = {},
    const SweepTimes *times = nullptr, StemCentreLmCache *cache = nullptr);

}  // namespace forestslam::registration
