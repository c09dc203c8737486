#include "forestslam/features/voxel_grid.hpp"

#include <cmath>
#include <cstdint>
#include <unordered_map>

namespace forestslam::features {

namespace {

// 21 bits per axis around the origin: +-1e6 voxels, enough for any plot at cm voxels.
std::uint64_t voxelKey(const Eigen::Vector3d &p, double inv) {
    auto axis = [inv](double v) {
        const auto i = static_cast<std::int64_t>(std::floor(v * inv)) + (1 << 20);
        return static_cast<std::uint64_t>(i) & 0x1FFFFFu;
    };
    return (axis(p.x()) << 42) | (axis(p.y()) << 21) | axis(p.z());
}

}  // namespace

Points3 voxelDownsample(const Eigen::Ref<const Points3> &points, double voxel_m,
                        std::vector<int> &representative) {
    representative.clear();
    if (!(voxel_m > 0.0)) {
        Points3 out(points.rows(), 3);
        Eigen::Index n = 0;
        for (Eigen::Index i = 0; i < points.rows(); ++i) {
            if (points.row(i).allFinite()) {
                out.row(n++) = points.row(i);
                representative.push_back(static_cast<int>(i));
            }
        }
        out.conservativeResize(n, 3);
        return out;
    }
    const double inv = 1.0 / voxel_m;
    std::unordered_map<std::uint64_t, int> slot;
    slot.reserve(static_cast<std::size_t>(points.rows()));
    std::vector<Eigen::Vector3d> sum;
    std::vector<int> count;
    for (Eigen::Index i = 0; i < points.rows(); ++i) {
        const Eigen::Vector3d p = points.row(i).transpose();
        if (!p.allFinite()) continue;
        auto [it, inserted] = slot.emplace(voxelKey(p, inv), static_cast<int>(sum.size()));
        if (inserted) {
            sum.push_back(p);
            count.push_back(1);
            representative.push_back(static_cast<int>(i));
        } else {
            sum[it->second] += p;
            ++count[it->second];
        }
    }
    Points3 out(static_cast<Eigen::Index>(sum.size()), 3);
    for (std::size_t k = 0; k < sum.size(); ++k) {
        out.row(static_cast<Eigen::Index>(k)) = (sum[k] / count[k]).transpose();
    }
    return out;
}

Points3 voxelDownsample(const Eigen::Ref<const Points3> &points, double voxel_m) {
    std::vector<int> unused;
    return voxelDownsample(points, voxel_m, unused);
}

}  // namespace forestslam::features
