// A small static KD-tree for k-nearest-neighbour search over low-dimensional feature vectors
// (the 8-D triangle-star features), plus a uniform grid for gated 2D nearest-point look-ups.
#pragma once

#include <cstdint>
#include <unordered_map>
#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam::localization {

class KdTree {
  public:
    using Matrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

    KdTree() = default;
    // points (N,D), one feature per row. Build O(N log N).
    explicit KdTree(Matrix points, int leaf_size = 8);

    // Up to k nearest rows to query (D,) within max_distance, nearest first (another length of
    // query is std::invalid_argument).
    void knn(const Eigen::Ref<const Eigen::VectorXd> &query, int k, double max_distance,
             std::vector<int> &indices, std::vector<double> &distances) const;

    Eigen::Index size() const { return points_.rows(); }
    Eigen::Index dims() const { return points_.cols(); }

  private:
    struct Node {
        int lo, hi;        // range in order_
        int dim = -1;      // -1: leaf
        double split = 0;  // coordinate of the median
        int left = -1, right = -1;
    };
    int build(int lo, int hi, int leaf_size);
    void search(int node, const double *q, int k, std::vector<std::pair<double, int>> &heap,
                double &worst) const;

    Matrix points_;
    std::vector<int> order_;
    std::vector<Node> nodes_;
};

// Uniform grid over 2D points for "nearest point within a gate" queries in O(1).
class PointGrid {
  public:
    PointGrid() = default;
    PointGrid(const Eigen::Ref<const Points2> &xy, double cell_m);

    // Index of the nearest point within gate_m of (x, y), or -1; squared distance in *d2.
    int nearest(double x, double y, double gate_m, double *d2 = nullptr) const;

  private:
    static uint64_t key(int64_t ix, int64_t iy) {
        return (static_cast<uint64_t>(static_cast<uint32_t>(ix)) << 32) | static_cast<uint32_t>(iy);
    }
    void buildOccupancy();
    bool maybeOccupied(int64_t ix, int64_t iy) const;

    Points2 xy_;
    double cell_ = 1.0;
    std::unordered_map<uint64_t, std::pair<int, int>> cells_;  // key -> [begin, end) in ids_
    std::vector<int> ids_;
    // Occupancy bits over the bounding box (when it has at most kMaxBits cells): most cells of
    // a forest are empty, and a bit test is much cheaper than a hash look-up that misses.
    std::vector<uint64_t> occupied_;
    int64_t x0_ = 0, y0_ = 0, nx_ = 0, ny_ = 0;
};

}  // namespace forestslam::localization
