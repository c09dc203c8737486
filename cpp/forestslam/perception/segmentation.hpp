// Coarse clustering of the filtered (stem-candidate) points: range-image divide-and-merge for
// single scans (Zhao et al., ICRA 2022), 3D Euclidean clustering for maps / TLS clouds, and the
// adaptive DBSCAN refinement of Gupta et al. 2023.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "forestslam/common/types.hpp"
#include "forestslam/perception/config.hpp"

namespace forestslam::perception {

using Clusters = std::vector<std::vector<int>>;  // rows of the input points, per cluster

// Pixel (row, col) of every point: row from `ring` when given (one entry per point, the beam
// index, ascending elevation), else the nearest beam elevation; col from the azimuth over the
// horizontal field of view. Points outside the image get row/col -1. `ring` is empty or has one
// entry per point (std::invalid_argument otherwise).
struct RangeImageProjection {
    std::vector<int> row, col;
};
RangeImageProjection projectToRangeImage(const Eigen::Ref<const Points3> &points,
                                         const Eigen::Ref<const Eigen::VectorXi> &ring,
                                         const SensorGeometry &sensor);

// Divide-and-merge: local clusters per block of `block_cols` columns by the neighbour criterion
// (Bogoslavskyi angle beta and a distance cap), then clusters of adjacent blocks merged when
// enough pixel pairs on their shared edge vote for it. Clusters smaller than `min_size` dropped.
Clusters rangeImageClusters(const Eigen::Ref<const Points3> &points,
                            const RangeImageProjection &projection, const SensorGeometry &sensor,
                            const SegmentationConfig &options, int min_size);

// 3D Euclidean clustering (PCL) for clouds without a range image.
Clusters euclideanClusters(const Eigen::Ref<const Points3> &points, double tolerance_m,
                           int min_size);

// DBSCAN of `rows` of `points` with radius eps and at least `min_neighbours` other points for a
// core point; noise dropped. Returns sub-clusters (rows of `points`).
Clusters dbscan(const Eigen::Ref<const Points3> &points, const std::vector<int> &rows, double eps,
                int min_neighbours);

// The adaptive eps of the paper: k * theta_V * |mean_xy(cluster)|, clamped to [min, max].
double adaptiveEps(const Eigen::Ref<const Points3> &points, const std::vector<int> &rows,
                   double theta_v_rad, const SegmentationConfig &options);

}  // namespace forestslam::perception
