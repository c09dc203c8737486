// Pre-processing of one scan (or one map cloud): intensity filter, ground segmentation, and the
// adaptive ring-based normal filter that keeps stem-like (vertical-surface) points.
#pragma once

#include <Eigen/Core>
#include <limits>
#include <vector>

#include "forestslam/common/types.hpp"
#include "forestslam/perception/config.hpp"

namespace forestslam::perception {

// Rows whose intensity is finite and <= threshold (foliage returns brighter); all rows when the
// threshold is NaN or `intensity` is empty (the sensor has no intensity); any other length than
// `rows` is std::invalid_argument.
std::vector<int> intensityFilter(const Eigen::Ref<const Eigen::VectorXd> &intensity,
                                 double threshold, Eigen::Index rows);

// Ground height on a regular XY grid, from the ground cells; holes within a few cells are
// filled from neighbours, farther away it is NaN.
struct GroundGrid {
    double cell = 0.5;
    Eigen::Vector2d origin = Eigen::Vector2d::Zero();
    Eigen::MatrixXd z;  // (rows = y cells, cols = x cells), NaN = unknown
    double heightAt(double x, double y) const;
};

struct GroundSegmentation {
    std::vector<char> is_ground;  // one flag per input row
    GroundGrid grid;
    int ground_count = 0;
};

// Approximate progressive morphological filter (PCL) on the lowest point per cell, then every
// point labelled by its height above its cell's ground point (see GroundConfig).
GroundSegmentation segmentGround(const Eigen::Ref<const Points3> &points,
                                 const GroundConfig &options);

// Ground rows thinned to one point (the lowest) per voxel: the ground output for ICP and maps.
Points3 thinGround(const Eigen::Ref<const Points3> &points, const std::vector<char> &is_ground,
                   double voxel_m);

struct NormalFilterResult {
    std::vector<int> kept;  // rows of the input that pass (vertical surface, dense enough)
    size_t own_rows = 0;    // the first own_rows of `kept` pass without the evidence rows
    Points3 normals;        // (kept.size(), 3) unit normals of the kept rows
    std::vector<double> radius_per_ring;  // search radius used per ring (one value in fixed mode)
};

// Adaptive ring-based normal estimation and outlier filter over `candidates` rows of `points`
// (non-ground). Rings in the sensor XY plane, radii geomspace(ring_min_m, ring_max_m, rings);
// per ring radius radius_scale * theta_v * (r_in + r_out) / 2 (or fixed_radius_m). `grid`
// limits candidates to the height band above ground when it knows the ground there. Rows from
// `evidence_from` on (the returns the intensity filter removed, appended after the kept ones)
// are evidence: the rows before them are filtered first as if they had never been seen (the
// first own_rows of `kept`, with the same normals), then the rows that failed that and the
// evidence rows with every row as neighbours (appended after them).
NormalFilterResult normalFilter(
    const Eigen::Ref<const Points3> &points, const std::vector<int> &candidates, double theta_v_rad,
    const NormalFilterConfig &options, const GroundGrid *grid,
    Eigen::Index evidence_from = std::numeric_limits<Eigen::Index>::max());

}  // namespace forestslam::perception
