// The neighbourhood scatter matrix the core's PCA normals share (ICP's plane target and
// perception's normal filter).
#pragma once

#include <Eigen/Core>
#include <utility>
#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam {

// Sum of the outer products of the rows `nn` lists (pairs of squared distance and row, as the
// k-d tree gives them) about their mean: the covariance times their count.
inline Eigen::Matrix3d neighbourScatter(const Eigen::Ref<const Points3> &points,
                                        const std::vector<std::pair<double, int>> &nn) {
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto &[d2, j] : nn) mean += points.row(j).transpose();
    mean /= static_cast<double>(nn.size());
    Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
    for (const auto &[d2, j] : nn) {
        const Eigen::Vector3d d = points.row(j).transpose() - mean;
        scatter.noalias() += d * d.transpose();
    }
    return scatter;
}

}  // namespace forestslam
