#include "forestslam/registration/tree_correspondences.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace forestslam::registration {

std::vector<std::pair<int, int>> matchTrees(const Eigen::Ref<const Points3> &source,
                                            const Eigen::Ref<const Points3> &target,
                                            const Pose3 &T_target_source_predicted, double gate_m,
                                            double ratio) {
    if (!(gate_m > 0.0) || !std::isfinite(gate_m))
        throw std::invalid_argument("matchTrees: gate_m must be > 0 (got " +
                                    std::to_string(gate_m) + ")");
    if (!(ratio > 0.0 && ratio <= 1.0))
        throw std::invalid_argument("matchTrees: ratio must be in (0, 1] (got " +
                                    std::to_string(ratio) + ")");
    std::vector<std::pair<int, int>> pairs;
    const Eigen::Index n = source.rows(), m = target.rows();
    if (n == 0 || m == 0) return pairs;
    const Points3 moved = transformPoints(T_target_source_predicted, source);
    constexpr double kInf = std::numeric_limits<double>::infinity();
    // Dense distance table: stems per scan are tens, so O(K*M) is the fast path.
    Eigen::MatrixXd d2(n, m);
    for (Eigen::Index i = 0; i < n; ++i) {
        for (Eigen::Index j = 0; j < m; ++j) {
            const double dx = moved(i, 0) - target(j, 0), dy = moved(i, 1) - target(j, 1);
            const double v = dx * dx + dy * dy;
            d2(i, j) = std::isfinite(v) ? v : kInf;
        }
    }
    std::vector<Eigen::Index> best_target(n, -1), best_source(m, -1);
    for (Eigen::Index j = 0; j < m; ++j) {
        Eigen::Index arg;
        if (std::isfinite(d2.col(j).minCoeff(&arg))) best_source[j] = arg;
    }
    const double gate2 = gate_m * gate_m;
    for (Eigen::Index i = 0; i < n; ++i) {
        Eigen::Index j;
        const double best = d2.row(i).minCoeff(&j);
        if (!(best <= gate2) || best_source[j] != i) continue;
        if (ratio < 1.0 && m > 1) {
            double second = kInf;
            for (Eigen::Index k = 0; k < m; ++k)
                if (k != j) second = std::min(second, d2(i, k));
            // distance ratio test on squared distances
            if (best > ratio * ratio * second) continue;
        }
        pairs.emplace_back(static_cast<int>(i), static_cast<int>(j));
    }
    return pairs;
}

}  // namespace forestslam::registration
