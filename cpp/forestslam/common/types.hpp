// Types at the boundary of the core API: Eigen only, row-major (N,3) so numpy maps without copy.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <vector>

namespace forestslam {

// (N,3) points, one per row, float64: the layout of a C-contiguous numpy array.
using Points3 = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
using Points2 = Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>;
using Pose3 = Eigen::Isometry3d;  // named by frames at use: T_world_sensor, T_target_source

// Rows whose three coordinates are all finite.
Points3 finiteRows(const Eigen::Ref<const Points3> &points);

// Rows selected by index, in the given order.
Points3 selectRows(const Eigen::Ref<const Points3> &points, const std::vector<int> &indices);

// Apply T to every row.
Points3 transformPoints(const Pose3 &T, const Eigen::Ref<const Points3> &points);

}  // namespace forestslam
