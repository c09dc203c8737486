// Voxel downsampling by hashing (no dense grid, so huge or far-apart clouds are fine).
#pragma once

#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam::features {

// One point per occupied voxel: the centroid of its points. Non-finite rows are dropped;
// voxel_m <= 0 returns the finite rows unchanged.
Points3 voxelDownsample(const Eigen::Ref<const Points3> &points, double voxel_m);

// Same, also returning for each output point the index of one input point of its voxel
// (the first one seen), e.g. to carry attributes along.
Points3 voxelDownsample(const Eigen::Ref<const Points3> &points, double voxel_m,
                        std::vector<int> &representative);

}  // namespace forestslam::features
