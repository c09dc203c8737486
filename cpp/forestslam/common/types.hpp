// Types at the boundary of the core API: Eigen only, row-major (N,3) so numpy maps without copy.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <vector>

namespace forestslam {

// (N,3) points, one per row, float64: the layout of a C-contiguous numpy array.
using Points3 = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
using Points2 = Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>;
// Every pose at the API, named by frames at use: T_world_sensor, T_target_source. Python sees a
// (4,4) float64 array.
using Pose3 = Eigen::Isometry3d;
// Twists and covariances over (tx, ty, tz, rx, ry, rz).
using Vector6d = Eigen::Matrix<double, 6, 1>;
using Matrix6d = Eigen::Matrix<double, 6, 6>;

// Rows whose three coordinates are all finite.
Points3 finiteRows(const Eigen::Ref<const Points3> &points);

// Rows selected by index, in the given order (std::out_of_range for an index outside the rows).
Points3 selectRows(const Eigen::Ref<const Points3> &points, const std::vector<int> &indices);

// Throws std::invalid_argument "<where>: <size> <what> for <rows> points" unless size == rows
// (or size == 0 when the field is optional): per-point fields must match their points.
void requirePerPoint(const char *where, const char *what, Eigen::Index size, Eigen::Index rows,
                     bool optional = false);

// Apply T to every row.
Points3 transformPoints(const Pose3 &T, const Eigen::Ref<const Points3> &points);

}  // namespace forestslam
