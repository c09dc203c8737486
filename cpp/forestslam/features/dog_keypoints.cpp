#include "forestslam/features/dog_keypoints.hpp"

#include <pcl/filters/statistical_outlier_removal.h>
#include <pcl/kdtree/kdtree_flann.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <map>
#include <numeric>

#include "forestslam/common/pcl_adapter.hpp"
#include "forestslam/features/voxel_grid.hpp"

namespace forestslam {

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

    // Statistical outlier removal: isolated returns (dust, twigs, mixed pixels) would
    // otherwise give the strongest responses.
    auto cloud = detail::toPcl(sampled);
    if (config.outlier_neighbours > 0 && cloud->size() > static_cast<std::size_t>(
                                                            config.outlier_neighbours)) {
        pcl::StatisticalOutlierRemoval<pcl::PointXYZ> sor;
        sor.setInputCloud(cloud);
        sor.setMeanK(config.outlier_neighbours);
        sor.setStddevMulThresh(config.outlier_std_ratio);
        auto filtered = pcl::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
        sor.filter(*filtered);
        cloud = filtered;
    }
    const Points3 pts = detail::fromPcl(*cloud);
    const Eigen::Index n = pts.rows();
    if (n < std::max(config.min_neighbours, 3)) return result;

    pcl::KdTreeFLANN<pcl::PointXYZ> tree;
    tree.setInputCloud(cloud);

    // Gaussian-weighted means at two scales from one neighbourhood search; the DoG response
    // is the displacement between them (rigid-motion invariant, large at corners, stems,
    // branches, small on flat ground).
    const double radius = 3.0 * config.sigma_large_m;
    const double a_small = -0.5 / (config.sigma_small_m * config.sigma_small_m);
    const double a_large = -0.5 / (config.sigma_large_m * config.sigma_large_m);
    std::vector<double> response(static_cast<std::size_t>(n), -1.0);
    std::vector<int> idx;
    std::vector<float> d2;
    for (Eigen::Index i = 0; i < n; ++i) {
        if (tree.radiusSearch((*cloud)[i], radius, idx, d2) < config.min_neighbours) continue;
        Eigen::Vector3d s_small = Eigen::Vector3d::Zero(), s_large = Eigen::Vector3d::Zero();
        double w_small = 0.0, w_large = 0.0;
        for (std::size_t k = 0; k < idx.size(); ++k) {
            const Eigen::Vector3d q = pts.row(idx[k]).transpose();
            const double ws = std::exp(a_small * d2[k]);
            const double wl = std::exp(a_large * d2[k]);
            s_small += ws * q;
            s_large += wl * q;
            w_small += ws;
            w_large += wl;
        }
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

}  // namespace forestslam
