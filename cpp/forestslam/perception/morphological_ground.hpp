// Ground cells of a min-grid by PCL's approximate progressive morphological filter, computed
// without PCL: the same result, several times faster (the per-scan ground stage).
#pragma once

#include <Eigen/Core>
#include <vector>

#include "forestslam/perception/config.hpp"

namespace forestslam::perception {

// Indices of `cells` (the lowest point of each grid cell) that
// pcl::ApproximateProgressiveMorphologicalFilter, with `options` (window, slope, distances,
// base, exponential) and cell size `cell`, keeps as ground, in input order.
std::vector<int> morphologicalGround(const std::vector<Eigen::Vector3f> &cells, float cell,
                                     const GroundConfig &options);

}  // namespace forestslam::perception
