// Voxel downsampling by hashing (no dense grid, so huge or far-apart clouds are fine).
#pragma once

#include <cstdint>
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

// Points grouped by voxel, the voxels in the order of their cell indices (x, then y, then z):
// the grouping a sort of packed voxel keys gives, by a radix sort of compact keys instead (3x
// fewer CPU than numpy's argsort on a million-point map). Cells are floor((p - origin) / voxel_m)
// per axis, as numpy computes them.
struct VoxelGroups {
    Eigen::Matrix<std::int64_t, Eigen::Dynamic, 1> order;    // (N,) points, voxel by voxel
    Eigen::Matrix<std::int64_t, Eigen::Dynamic, 1> start;    // (M,) first slot of each voxel
    Eigen::Matrix<std::int64_t, Eigen::Dynamic, 1> inverse;  // (N,) voxel of each point
};

// std::invalid_argument for a non-finite point, voxel_m <= 0, or cells spanning more than 2^21
// voxels along an axis (the packed keys' limit).
VoxelGroups groupByVoxel(const Eigen::Ref<const Points3> &points, const Eigen::Vector3d &origin,
                         double voxel_m);

}  // namespace forestslam::features
