// Robust 2D circle fit for stem cross-sections: RANSAC on 3-point circles for the consensus set,
// Taubin algebraic fit on it, then geometric (orthogonal distance) Levenberg-Marquardt with Tukey
// weights. A LiDAR sees about a third of a stem, so the result carries its own quality: inliers,
// RMS residual and arc coverage (how much of the circumference holds inliers).
//
// fitCircleRays refines that fit with the LiDAR's own noise model when the view origin of every
// point is known: the noise lies along the beam (range), not across it. An orthogonal-distance
// fit treats it as isotropic and, on the one-sided arcs a LiDAR sees, shrinks the circle:
// -1.8 cm DBH at 3 cm range noise on one view, -0.9 cm over 25 views along a path (measured,
// bench/dbh_bench.py). The range model is unbiased there (within 0.05 cm).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam {

struct CircleFitConfig {
    double inlier_threshold_m = 0.03;  // |distance - radius| counted as an inlier
    double min_radius_m = 0.0;         // candidate circles outside the bounds are rejected
    double max_radius_m = std::numeric_limits<double>::infinity();
    int max_ransac_iterations = 200;  // adaptive stop at 99 % confidence before this cap
    int refine_iterations = 30;       // geometric LM iterations
    int arc_sectors = 36;             // angular sectors for the arc coverage (10 deg each)
    std::uint32_t seed = 42;          // RANSAC sampling is deterministic for a given seed
    // fitCircleRays: spread of the points across their beams (beam footprint, bark, pose
    // jitter of accumulated scans); the range spread is estimated from the residuals.
    double lateral_sigma_m = 0.005;
    // fitCircleRays keeps the orthogonal fit unless the residuals of beams facing the surface
    // are at least this many times those of grazing beams (noise along the beam).
    double min_range_anisotropy = 1.2;
};

struct CircleFit {
    bool valid = false;  // false: fewer than 3 usable points, collinear, or radius out of bounds
    Eigen::Vector2d centre = Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN());
    double radius = std::numeric_limits<double>::quiet_NaN();
    int inliers = 0;                                          // points within the threshold
    double rms_m = std::numeric_limits<double>::quiet_NaN();  // RMS of inlier residuals
    double arc_coverage = 0.0;                                // occupied sectors / all sectors
    std::vector<int> inlier_indices;                          // rows of the input
    // Covariance of (centre x, centre y, radius) from the inliers (circleCovariance with the
    // 3 fitted parameters); infinite for fewer than 4 inliers or a degenerate arc.
    Eigen::Matrix3d covariance = Eigen::Matrix3d::Constant(std::numeric_limits<double>::infinity());
    // Standard deviation (m) of the radius: sqrt(covariance(2, 2)).
    double radiusStd() const;
};

// Covariance of (centre x, centre y, radius) of a geometric circle fit (centre, radius) to
// rows `rows` of xy: sigma^2 (J^T J)^-1 with J_i = [-(p_i - c) / |p_i - c|, -1] and sigma^2
// the residual variance, sum e_i^2 / (n - fitted_parameters), at least min_variance_m2 (an
// exact fit through its points does not make the circle exact). On a short arc the centre and
// the radius trade off along the view, so it grows without bound as the arc shrinks.
// fitted_parameters: 3 when (centre, radius) were fitted to these rows; 0 when the circle
// comes from elsewhere (a cylinder's section) and is only evaluated on them.
// Infinite for fewer than 3 rows, no more rows than fitted_parameters, or |det J^T J| <= 1e-12.
// A row at the centre itself adds its residual but no direction.
Eigen::Matrix3d circleCovariance(const Eigen::Ref<const Points2> &xy, const std::vector<int> &rows,
                                 const Eigen::Vector2d &centre, double radius,
                                 int fitted_parameters = 3, double min_variance_m2 = 1e-12);

// Algebraic (Taubin) fit of all rows; no robustness. Invalid for < 3 points or collinear input.
CircleFit fitCircleAlgebraic(const Eigen::Ref<const Points2> &xy);

// Robust fit; non-finite rows are ignored (indices still refer to the input rows).
CircleFit fitCircle(const Eigen::Ref<const Points2> &xy, const CircleFitConfig &options = {});

// fitCircle with a weight per row (e.g. how many observations a voxel map's point stands
// for): a row of weight w counts as w rows in the RANSAC draws (weighted sampling) and
// consensus, the algebraic and geometric fits, rms_m and the covariance (sigma^2 from the
// weighted residuals over summed weight - 3), so integer weights give the fit of the rows
// repeated that often, without the copies. inliers and inlier_indices stay rows.
// std::invalid_argument unless weights has one finite, non-negative value per row.
CircleFit fitCircleWeighted(const Eigen::Ref<const Points2> &xy,
                            const Eigen::Ref<const Eigen::VectorXd> &weights,
                            const CircleFitConfig &options = {});

// Robust fit refined by maximum likelihood under range noise: point i was measured from the
// view origin origins.row(i) (the sensor position, same frame), its error lies along that beam.
// Residual of a beam that hits the circle: measured range - range to the circle's near side;
// of a beam that misses it: the range to the beam's closest approach and the miss distance
// (over lateral_sigma_m). Range sigma from the residuals (MAD), Cauchy weights. Returns the
// orthogonal fit when the spread is not along the beams (min_range_anisotropy) or the
// refinement fails or wanders off.
CircleFit fitCircleRays(const Eigen::Ref<const Points2> &xy,
                        const Eigen::Ref<const Points2> &origins,
                        const CircleFitConfig &options = {});

// fitCircleRays with a weight per row, as fitCircleWeighted (the range spread is the weighted
// median, the refinement's weights are the rows' times the Cauchy weights).
CircleFit fitCircleRaysWeighted(const Eigen::Ref<const Points2> &xy,
                                const Eigen::Ref<const Points2> &origins,
                                const Eigen::Ref<const Eigen::VectorXd> &weights,
                                const CircleFitConfig &options = {});

// Fraction of `sectors` equal angular sectors around `centre` that hold at least one of `rows`.
double arcCoverage(const Eigen::Ref<const Points2> &xy, const std::vector<int> &rows,
                   const Eigen::Vector2d &centre, int sectors);

// Block jackknife of the radius of a circle (centre, radius) fitted to xy: its inliers
// (within options.inlier_threshold_m), ordered by angle from the widest gap, are split into
// `blocks` contiguous runs of equal count, and the circle is refitted from (centre, radius)
// by weighted geometric least squares without each run in turn; returns
// sqrt((B - 1) / B * sum (r_b - mean)^2), the standard deviation of the radius from which part
// of the arc is seen. A stem's shape (ovality, polygon faces, flare) bends its arc
// systematically: the covariance, which takes the residuals as white noise, does not see it.
// Independent of the rows' order; infinite for fewer than 2 * blocks inliers, blocks < 2 or a
// failed refit. std::invalid_argument unless weights has one finite, non-negative value per row.
double circleArcJackknife(const Eigen::Ref<const Points2> &xy,
                          const Eigen::Ref<const Eigen::VectorXd> &weights,
                          const Eigen::Vector2d &centre, double radius, int blocks,
                          const CircleFitConfig &options = {});

}  // namespace forestslam
