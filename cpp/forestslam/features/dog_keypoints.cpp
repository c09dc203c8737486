#include "forestslam/features/dog_keypoints.hpp"

#include <pcl/kdtree/kdtree_flann.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <map>
#include <numeric>
#include <vector>

#include "forestslam/common/pcl_adapter.hpp"
#include "forestslam/features/voxel_grid.hpp"

namespace forestslam::features {

namespace {

std::int64_t bucketKey(const Eigen::Vector3d &p, double bucket_m) {
    auto axis = [bucket_m](double v) {
        return static_cast<std::int64_t>(std::floor(v / bucket_m)) & 0xFFFFF;
    };
    return (axis(p.x()) << 40) | (axis(p.y()) << 20) | axis(p.z());
}

}  // namespace

DogKeypoints detectDogKeypoints(const Eigen::Ref<const Points3> &points,
                                const DogKeypointsConfig &config) {
    DogKeypoints result;
    result.points.resize(0, 3);
    result.response.resize(0);
    const Points3 sampled = voxelDownsample(points, config.voxel_m);
    if (sampled.rows() < std::max(config.min_neighbours, 3) || config.max_keypoints <= 0) {
        return result;
    }

    auto cloud = detail::toPcl(sampled);
    const Points3 pts = detail::fromPcl(*cloud);
    const Eigen::Index n = pts.rows();
    if (n < std::max(config.min_neighbours, 3)) return result;

    pcl::KdTreeFLANN<pcl::PointXYZ> tree(false);  // unsorted radius results: not needed
    tree.setInputCloud(cloud);

    // Gaussian-weighted means at two scales from one neighbourhood search; the DoG response
    // is the displacement between them (rigid-motion invariant, large at corners, stems,
    // branches, small on flat ground).
    const double r_small = 3.0 * config.sigma_small_m;
    const double r_large = 3.0 * std::max(config.sigma_large_m, config.sigma_small_m);
    const double r2_small = r_small * r_small, r2_large = r_large * r_large;
    const double a_small = -0.5 / (config.sigma_small_m * config.sigma_small_m);
    const double a_large = -0.5 / (config.sigma_large_m * config.sigma_large_m);
    // Gaussian weights by table over the squared distance (linear interpolation, relative
    // error ~1e-5): exp() per neighbour pair dominated the cost.
    constexpr int kBins = 1024;
    auto table = [](double a, double r2) {
        std::vector<double> t(kBins + 2);
        for (int k = 0; k <= kBins + 1; ++k) t[k] = std::exp(a * k * r2 / kBins);
        return t;
    };
    const std::vector<double> tab_small = table(a_small, r2_small);
    const std::vector<double> tab_large = table(a_large, r2_large);
    auto weight = [](const std::vector<double> &t, double d2, double r2) {
        const double u = std::min(d2, r2) / r2 * kBins;
        const auto b = static_cast<int>(u);
        return t[b] + (u - b) * (t[b + 1] - t[b]);
    };

    std::vector<double> response(static_cast<std::size_t>(n), -1.0);
    std::vector<int> idx;
    std::vector<float> d2;
    for (Eigen::Index i = 0; i < n; ++i) {
        if (tree.radiusSearch((*cloud)[i], r_large, idx, d2) < config.min_neighbours) continue;
        Eigen::Vector3d s_small = Eigen::Vector3d::Zero(), s_large = Eigen::Vector3d::Zero();
        double w_small = 0.0, w_large = 0.0;
        int near = 0;
        for (std::size_t k = 0; k < idx.size(); ++k) {
            const Eigen::Vector3d q = pts.row(idx[k]).transpose();
            const double dk = d2[k];
            const double wl = weight(tab_large, dk, r2_large);
            s_large += wl * q;
            w_large += wl;
            if (dk <= r2_small) {
                const double ws = weight(tab_small, dk, r2_small);
                s_small += ws * q;
                w_small += ws;
                ++near;
            }
        }
        // Outlier removal: isolated returns (dust, twigs, mixed pixels) would otherwise give
        // the strongest responses; they never become keypoints.
        if (near < std::max(config.outlier_neighbours, 1)) continue;
        response[static_cast<std::size_t>(i)] = (s_small / w_small - s_large / w_large).norm();
    }

    // Non-maximum suppression, strongest first.
    std::vector<int> order(static_cast<std::size_t>(n));
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(), [&](int a, int b) { return response[a] > response[b]; });
    std::vector<char> suppressed(static_cast<std::size_t>(n), 0);
    std::vector<int> maxima;
    for (int i : order) {
        if (response[i] <= 0.0) break;
        if (suppressed[i]) continue;
        maxima.push_back(i);
        tree.radiusSearch((*cloud)[i], config.nms_radius_m, idx, d2);
        for (int j : idx) suppressed[j] = 1;
    }

    // Even spread: round-robin over voxel buckets, each bucket giving its best maxima first.
    std::map<std::int64_t, std::vector<int>> buckets;
    for (int i : maxima) {  // maxima are in descending response order
        buckets[bucketKey(pts.row(i).transpose(), config.bucket_m)].push_back(i);
    }
    std::vector<int> chosen;
    for (std::size_t rank = 0; chosen.size() < static_cast<std::size_t>(config.max_keypoints);
         ++rank) {
        std::vector<int> round;
        for (const auto &[key, members] : buckets) {
            if (rank < members.size()) round.push_back(members[rank]);
        }
        if (round.empty()) break;
        std::sort(round.begin(), round.end(),
                  [&](int a, int b) { return response[a] > response[b]; });
        for (int i : round) {
            if (chosen.size() >= static_cast<std::size_t>(config.max_keypoints)) break;
            chosen.push_back(i);
        }
    }
    result.points = selectRows(pts, chosen);
    result.response.resize(static_cast<Eigen::Index>(chosen.size()));
    for (std::size_t k = 0; k < chosen.size(); ++k) result.response[k] = response[chosen[k]];
    return result;
}

}  // namespace forestslam::features
