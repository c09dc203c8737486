#include "forestslam/common/types.hpp"

#include <stdexcept>
#include <string>

namespace forestslam {

Points3 finiteRows(const Eigen::Ref<const Points3> &points) {
    std::vector<int> keep;
    keep.reserve(points.rows());
    for (Eigen::Index i = 0; i < points.rows(); ++i) {
        if (points.row(i).allFinite()) keep.push_back(static_cast<int>(i));
    }
    return selectRows(points, keep);
}

Points3 selectRows(const Eigen::Ref<const Points3> &points, const std::vector<int> &indices) {
    Points3 out(indices.size(), 3);
    for (size_t k = 0; k < indices.size(); ++k) {
        if (indices[k] < 0 || indices[k] >= points.rows())
            throw std::out_of_range("selectRows: row " + std::to_string(indices[k]) + " of " +
                                    std::to_string(points.rows()));
        out.row(k) = points.row(indices[k]);
    }
    return out;
}

void requirePerPoint(const char *where, const char *what, Eigen::Index size, Eigen::Index rows,
                     bool optional) {
    if (size == rows || (optional && size == 0)) return;
    throw std::invalid_argument(std::string(where) + ": " + std::to_string(size) + " " + what +
                                " for " + std::to_string(rows) + " points");
}

Points3 transformPoints(const Pose3 &T, const Eigen::Ref<const Points3> &points) {
    Points3 out = (points * T.linear().transpose()).rowwise() + T.translation().transpose();
    return out;
}

}  // namespace forestslam
