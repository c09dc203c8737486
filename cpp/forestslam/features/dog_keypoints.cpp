#include "forestslam/features/dog_keypoints.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <map>
#include <numeric>
#include <unordered_map>
#include <vector>

#include "forestslam/common/voxel_key.hpp"
#include "forestslam/features/voxel_grid.hpp"

namespace forestslam::features {

namespace {

std::int64_t bucketKey(const Eigen::Vector3d &p, double bucket_m) {
    auto axis = [bucket_m](double v) {
        return static_cast<std::int64_t>(std::floor(v / bucket_m)) & 0xFFFFF;
    };
    return (axis(p.x()) << 40) | (axis(p.y()) << 20) | axis(p.z());
}

// Fixed-radius neighbours by a hash grid of cubic cells no smaller than the largest radius
// asked for: the neighbours of a point lie in the 27 cells around its own. The points of one
// cell are contiguous, and a cell's 27-cell candidates are gathered once for all its points
// (PCL's k-d tree spent more time per query than the ~40 neighbours of a point cost).
// Distances are single precision, as the k-d tree computed them (same neighbour sets).
// Not common/kdtree.hpp's KdTree3: it answers nearest / k-nearest queries, not all points within
// a radius, and here every point of the cloud asks for its ~40 neighbours, which one candidate
// list per cell serves without a tree descent per query.
class CellGrid {
  public:
    CellGrid(const Points3 &pts, double cell_m) : cell_(cell_m) {
        const auto n = static_cast<std::size_t>(pts.rows());
        xyz_.resize(n);
        cell_of_.resize(n);
        std::vector<std::uint64_t> key(n);
        for (std::size_t i = 0; i < n; ++i) {
            const auto r = static_cast<Eigen::Index>(i);
            xyz_[i] = pts.row(r).transpose().cast<float>();
            key[i] = voxelKey(pts(r, 0), pts(r, 1), pts(r, 2), cell_);
        }
        order_.resize(n);
        std::iota(order_.begin(), order_.end(), 0);
        std::stable_sort(order_.begin(), order_.end(),
                         [&](int a, int b) { return key[a] < key[b]; });
        for (std::size_t k = 0; k < n;) {
            std::size_t e = k;
            while (e < n && key[order_[e]] == key[order_[k]]) ++e;
            const int id = static_cast<int>(begin_.size());
            cells_.emplace(key[order_[k]], id);
            begin_.push_back(static_cast<int>(k));
            end_.push_back(static_cast<int>(e));
            for (std::size_t j = k; j < e; ++j) cell_of_[order_[j]] = id;
            k = e;
        }
    }

    int cells() const { return static_cast<int>(begin_.size()); }
    // Points (indices) of cell c.
    const int *cellBegin(int c) const { return order_.data() + begin_[c]; }
    const int *cellEnd(int c) const { return order_.data() + end_[c]; }

    // Candidates of every point of cell c: the points of the 27 cells around it.
    void candidates(int c, std::vector<int> &out) const {
        out.clear();
        const Eigen::Vector3f &p = xyz_[static_cast<std::size_t>(*cellBegin(c))];
        const auto ix = cellIndex(p.x(), cell_), iy = cellIndex(p.y(), cell_),
                   iz = cellIndex(p.z(), cell_);
        for (std::int64_t dx = -1; dx <= 1; ++dx)
            for (std::int64_t dy = -1; dy <= 1; ++dy)
                for (std::int64_t dz = -1; dz <= 1; ++dz) {
                    const auto it = cells_.find(cellKey3(ix + dx, iy + dy, iz + dz));
                    if (it != cells_.end())
                        out.insert(out.end(), cellBegin(it->second), cellEnd(it->second));
                }
    }

    // Points within radius of point i (squared distances in d2), over its cell's candidates.
    void within(int i, const std::vector<int> &cand, float r2, std::vector<int> &idx,
                std::vector<float> &d2) const {
        idx.clear();
        d2.clear();
        const Eigen::Vector3f &q = xyz_[static_cast<std::size_t>(i)];
        for (int j : cand) {
            const Eigen::Vector3f &p = xyz_[static_cast<std::size_t>(j)];
            const float a = q.x() - p.x(), b = q.y() - p.y(), c = q.z() - p.z();
            const float dd = a * a + b * b + c * c;
            if (dd < r2) {
                idx.push_back(j);
                d2.push_back(dd);
            }
        }
    }

    int cellOf(int i) const { return cell_of_[static_cast<std::size_t>(i)]; }

  private:
    double cell_;
    std::vector<Eigen::Vector3f> xyz_;
    std::vector<int> order_, begin_, end_, cell_of_;
    std::unordered_map<std::uint64_t, int> cells_;
};

// Gaussian weights by table over the squared distance (linear interpolation, relative error
// ~1e-5): exp() per neighbour pair dominated the cost.
class GaussTable {
  public:
    GaussTable(double sigma_m, double radius_m) : r2_(radius_m * radius_m) {
        const double a = -0.5 / (sigma_m * sigma_m);
        t_.resize(kBins + 2);
        for (int k = 0; k <= kBins + 1; ++k) t_[k] = std::exp(a * k * r2_ / kBins);
    }
    double r2() const { return r2_; }
    double operator()(double d2) const {
        const double u = std::min(d2, r2_) / r2_ * kBins;
        const auto b = static_cast<int>(u);
        return t_[b] + (u - b) * (t_[b + 1] - t_[b]);
    }

  private:
    static constexpr int kBins = 1024;
    double r2_;
    std::vector<double> t_;
};

// DoG response per point (-1: too few neighbours, or an isolated return): Gaussian-weighted
// means at two scales from one neighbourhood search; the response is the displacement between
// them (rigid-motion invariant, large at corners, stems, branches, small on flat ground).
std::vector<double> dogResponses(const Points3 &pts, const CellGrid &grid,
                                 const DogKeypointsConfig &config) {
    const GaussTable small(config.sigma_small_m, 3.0 * config.sigma_small_m);
    const GaussTable large(config.sigma_large_m,
                           3.0 * std::max(config.sigma_large_m, config.sigma_small_m));
    std::vector<double> response(static_cast<std::size_t>(pts.rows()), -1.0);
    std::vector<int> idx, cand;
    std::vector<float> d2;
    const auto r2_large_f = static_cast<float>(large.r2());
    for (int c = 0; c < grid.cells(); ++c) {
        grid.candidates(c, cand);
        for (const int *it = grid.cellBegin(c); it != grid.cellEnd(c); ++it) {
            const int i = *it;
            grid.within(i, cand, r2_large_f, idx, d2);
            if (static_cast<int>(idx.size()) < config.min_neighbours) continue;
            Eigen::Vector3d s_small = Eigen::Vector3d::Zero(), s_large = Eigen::Vector3d::Zero();
            double w_small = 0.0, w_large = 0.0;
            int near = 0;
            for (std::size_t k = 0; k < idx.size(); ++k) {
                const Eigen::Vector3d q = pts.row(idx[k]).transpose();
                const double dk = d2[k];
                const double wl = large(dk);
                s_large += wl * q;
                w_large += wl;
                if (dk <= small.r2()) {
                    const double ws = small(dk);
                    s_small += ws * q;
                    w_small += ws;
                    ++near;
                }
            }
            // Outlier removal: isolated returns (dust, twigs, mixed pixels) would otherwise
            // give the strongest responses; they never become keypoints.
            if (near < std::max(config.outlier_neighbours, 1)) continue;
            response[static_cast<std::size_t>(i)] = (s_small / w_small - s_large / w_large).norm();
        }
    }
    return response;
}

// Non-maximum suppression within radius_m, strongest first -> maxima in descending response.
std::vector<int> localMaxima(const CellGrid &grid, const std::vector<double> &response,
                             double radius_m) {
    const auto n = response.size();
    std::vector<int> order(n);
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(), [&](int a, int b) { return response[a] > response[b]; });
    std::vector<char> suppressed(n, 0);
    std::vector<int> maxima, idx, cand;
    std::vector<float> d2;
    for (int i : order) {
        if (response[i] <= 0.0) break;
        if (suppressed[i]) continue;
        maxima.push_back(i);
        grid.candidates(grid.cellOf(i), cand);
        grid.within(i, cand, static_cast<float>(radius_m * radius_m), idx, d2);
        for (int j : idx) suppressed[j] = 1;
    }
    return maxima;
}

// Even spread: round-robin over voxel buckets, each bucket giving its best maxima first (maxima
// in descending response order), at most config.max_keypoints.
std::vector<int> spreadEvenly(const Points3 &pts, const std::vector<int> &maxima,
                              const std::vector<double> &response,
                              const DogKeypointsConfig &config) {
    std::map<std::int64_t, std::vector<int>> buckets;
    for (int i : maxima) buckets[bucketKey(pts.row(i).transpose(), config.bucket_m)].push_back(i);
    const auto max_keypoints = static_cast<std::size_t>(config.max_keypoints);
    std::vector<int> chosen;
    for (std::size_t rank = 0; chosen.size() < max_keypoints; ++rank) {
        std::vector<int> round;
        for (const auto &[key, members] : buckets) {
            if (rank < members.size()) round.push_back(members[rank]);
        }
        if (round.empty()) break;
        std::sort(round.begin(), round.end(),
                  [&](int a, int b) { return response[a] > response[b]; });
        for (int i : round) {
            if (chosen.size() >= max_keypoints) break;
            chosen.push_back(i);
        }
    }
    return chosen;
}

}  // namespace

DogKeypoints detectDogKeypoints(const Eigen::Ref<const Points3> &points,
                                const DogKeypointsConfig &config) {
    DogKeypoints result;
    result.points.resize(0, 3);
    result.response.resize(0);
    const int min_points = std::max(config.min_neighbours, 3);
    const Points3 sampled = voxelDownsample(points, config.voxel_m);
    if (sampled.rows() < min_points || config.max_keypoints <= 0) return result;
    // Single precision coordinates (keypoints are returned as such, as with PCL before).
    const Points3 pts = sampled.cast<float>().cast<double>();

    const double r_large = 3.0 * std::max(config.sigma_large_m, config.sigma_small_m);
    const CellGrid grid(pts, std::max(r_large, config.nms_radius_m));
    const std::vector<double> response = dogResponses(pts, grid, config);
    const std::vector<int> maxima = localMaxima(grid, response, config.nms_radius_m);
    const std::vector<int> chosen = spreadEvenly(pts, maxima, response, config);

    result.points = selectRows(pts, chosen);
    result.response.resize(static_cast<Eigen::Index>(chosen.size()));
    for (std::size_t k = 0; k < chosen.size(); ++k) result.response[k] = response[chosen[k]];
    return result;
}

}  // namespace forestslam::features
