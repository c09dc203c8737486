// Robust 2D circle fit for stem cross-sections: RANSAC on 3-point circles for the consensus set,
// Taubin algebraic fit on it, then geometric (orthogonal distance) Levenberg-Marquardt with Tukey
// weights. A LiDAR sees about a third of a stem, so the result carries its own quality: inliers,
// RMS residual and arc coverage (how much of the circumference holds inliers).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam {

struct CircleFitOptions {
    double inlier_threshold_m = 0.03;  // |distance - radius| counted as an inlier
    double min_radius_m = 0.0;         // candidate circles outside the bounds are rejected
    double max_radius_m = std::numeric_limits<double>::infinity();
    int max_ransac_iterations = 200;  // adaptive stop at 99 % confidence before this cap
    int refine_iterations = 30;       // geometric LM iterations
    int arc_sectors = 36;             // angular sectors for the arc coverage (10 deg each)
    std::uint32_t seed = 42;          // RANSAC sampling is deterministic for a given seed
};

struct CircleFit {
    bool valid = false;  // false: fewer than 3 usable points, collinear, or radius out of bounds
    Eigen::Vector2d centre = Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN());
    double radius = std::numeric_limits<double>::quiet_NaN();
    int inliers = 0;                                          // points within the threshold
    double rms_m = std::numeric_limits<double>::quiet_NaN();  // RMS of inlier residuals
    double arc_coverage = 0.0;                                // occupied sectors / all sectors
    std::vector<int> inlier_indices;                          // rows of the input
};

// Algebraic (Taubin) fit of all rows; no robustness. Invalid for < 3 points or collinear input.
CircleFit fitCircleAlgebraic(const Eigen::Ref<const Points2> &xy);

// Robust fit; non-finite rows are ignored (indices still refer to the input rows).
CircleFit fitCircle(const Eigen::Ref<const Points2> &xy, const CircleFitOptions &options = {});

// Fraction of `sectors` equal angular sectors around `centre` that hold at least one of `rows`.
double arcCoverage(const Eigen::Ref<const Points2> &xy, const std::vector<int> &rows,
                   const Eigen::Vector2d &centre, int sectors);

}  // namespace forestslam
