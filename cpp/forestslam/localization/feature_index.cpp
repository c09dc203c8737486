#include "forestslam/localization/feature_index.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace forestslam::localization {

KdTree::KdTree(Matrix points, int leaf_size) : points_(std::move(points)) {
    order_.resize(points_.rows());
    for (Eigen::Index i = 0; i < points_.rows(); ++i) order_[i] = static_cast<int>(i);
    if (points_.rows() > 0) build(0, static_cast<int>(points_.rows()), std::max(1, leaf_size));
}

int KdTree::build(int lo, int hi, int leaf_size) {
    const int id = static_cast<int>(nodes_.size());
    nodes_.push_back({lo, hi});
    if (hi - lo <= leaf_size) return id;
    // Split on the dimension of largest spread, at the median.
    int best_dim = 0;
    double best_spread = -1;
    for (Eigen::Index d = 0; d < points_.cols(); ++d) {
        double mn = std::numeric_limits<double>::max(), mx = std::numeric_limits<double>::lowest();
        for (int i = lo; i < hi; ++i) {
            const double v = points_(order_[i], d);
            mn = std::min(mn, v);
            mx = std::max(mx, v);
        }
        if (mx - mn > best_spread) {
            best_spread = mx - mn;
            best_dim = static_cast<int>(d);
        }
    }
    if (best_spread <= 0) return id;  // all equal: keep as a leaf
    const int mid = (lo + hi) / 2;
    std::nth_element(order_.begin() + lo, order_.begin() + mid, order_.begin() + hi,
                     [&](int a, int b) { return points_(a, best_dim) < points_(b, best_dim); });
    const double split = points_(order_[mid], best_dim);
    const int left = build(lo, mid, leaf_size);
    const int right = build(mid, hi, leaf_size);
    nodes_[id].dim = best_dim;
    nodes_[id].split = split;
    nodes_[id].left = left;
    nodes_[id].right = right;
    return id;
}

void KdTree::search(int node_id, const double *q, int k, std::vector<std::pair<double, int>> &heap,
                    double &worst) const {
    const Node &node = nodes_[node_id];
    if (node.dim < 0) {
        const Eigen::Index D = points_.cols();
        for (int i = node.lo; i < node.hi; ++i) {
            const int row = order_[i];
            const double *p = points_.data() + row * D;
            double d2 = 0;
            for (Eigen::Index d = 0; d < D && d2 < worst; ++d) d2 += (p[d] - q[d]) * (p[d] - q[d]);
            if (d2 >= worst) continue;
            heap.push_back({d2, row});
            std::push_heap(heap.begin(), heap.end());
            if (static_cast<int>(heap.size()) > k) {
                std::pop_heap(heap.begin(), heap.end());
                heap.pop_back();
            }
            if (static_cast<int>(heap.size()) == k) worst = std::min(worst, heap.front().first);
        }
        return;
    }
    const double diff = q[node.dim] - node.split;
    const int near = diff < 0 ? node.left : node.right;
    const int far = diff < 0 ? node.right : node.left;
    search(near, q, k, heap, worst);
    if (diff * diff < worst) search(far, q, k, heap, worst);
}

void KdTree::knn(const Eigen::Ref<const Eigen::VectorXd> &query, int k, double max_distance,
                 std::vector<int> &indices, std::vector<double> &distances) const {
    indices.clear();
    distances.clear();
    if (nodes_.empty() || k <= 0) return;
    if (query.size() != points_.cols())
        throw std::invalid_argument("KdTree::knn: a query of " + std::to_string(query.size()) +
                                    " dimensions for features of " +
                                    std::to_string(points_.cols()));
    std::vector<std::pair<double, int>> heap;
    heap.reserve(k + 1);
    double worst = std::isfinite(max_distance) ? max_distance * max_distance
                                               : std::numeric_limits<double>::max();
    worst = std::nextafter(worst, std::numeric_limits<double>::max());
    const Eigen::VectorXd q = query;
    search(0, q.data(), k, heap, worst);
    std::sort_heap(heap.begin(), heap.end());
    for (const auto &[d2, row] : heap) {
        indices.push_back(row);
        distances.push_back(std::sqrt(d2));
    }
}

PointGrid::PointGrid(const Eigen::Ref<const Points2> &xy, double cell_m)
    : xy_(xy), cell_(cell_m > 0 ? cell_m : 1.0) {
    std::vector<std::pair<uint64_t, int>> keyed;
    keyed.reserve(xy_.rows());
    for (Eigen::Index i = 0; i < xy_.rows(); ++i) {
        if (!std::isfinite(xy_(i, 0)) || !std::isfinite(xy_(i, 1))) continue;
        const auto ix = static_cast<int64_t>(std::floor(xy_(i, 0) / cell_));
        const auto iy = static_cast<int64_t>(std::floor(xy_(i, 1) / cell_));
        keyed.push_back({key(ix, iy), static_cast<int>(i)});
    }
    std::sort(keyed.begin(), keyed.end());
    ids_.resize(keyed.size());
    for (size_t i = 0; i < keyed.size(); ++i) {
        ids_[i] = keyed[i].second;
        auto it = cells_.find(keyed[i].first);
        if (it == cells_.end())
            cells_.emplace(keyed[i].first, std::make_pair(int(i), int(i) + 1));
        else
            it->second.second = static_cast<int>(i) + 1;
    }
    buildOccupancy();
}

void PointGrid::buildOccupancy() {
    constexpr int64_t kMaxBits = int64_t(1) << 27;  // 16 MB at most
    if (ids_.empty()) return;
    auto cell = [&](double v) { return static_cast<int64_t>(std::floor(v / cell_)); };
    int64_t x1 = 0, y1 = 0;
    for (size_t k = 0; k < ids_.size(); ++k) {
        const int64_t ix = cell(xy_(ids_[k], 0)), iy = cell(xy_(ids_[k], 1));
        if (k == 0) {
            x0_ = x1 = ix;
            y0_ = y1 = iy;
        }
        x0_ = std::min(x0_, ix);
        x1 = std::max(x1, ix);
        y0_ = std::min(y0_, iy);
        y1 = std::max(y1, iy);
    }
    nx_ = x1 - x0_ + 1;
    ny_ = y1 - y0_ + 1;
    if (nx_ > kMaxBits / ny_) return;  // too large: the hash look-up alone
    occupied_.assign((nx_ * ny_ + 63) / 64, 0);
    for (int id : ids_) {
        const int64_t bit = (cell(xy_(id, 0)) - x0_) * ny_ + (cell(xy_(id, 1)) - y0_);
        occupied_[bit / 64] |= uint64_t(1) << (bit % 64);
    }
}

bool PointGrid::maybeOccupied(int64_t ix, int64_t iy) const {
    if (occupied_.empty()) return true;
    if (ix < x0_ || iy < y0_ || ix >= x0_ + nx_ || iy >= y0_ + ny_) return false;
    const int64_t bit = (ix - x0_) * ny_ + (iy - y0_);
    return (occupied_[bit / 64] >> (bit % 64)) & 1;
}

int PointGrid::nearest(double x, double y, double gate_m, double *d2_out) const {
    if (!std::isfinite(x) || !std::isfinite(y) || cells_.empty()) return -1;
    // Only the cells the gate's square overlaps (4 at most when the gate is half a cell).
    const auto x0 = static_cast<int64_t>(std::floor((x - gate_m) / cell_));
    const auto x1 = static_cast<int64_t>(std::floor((x + gate_m) / cell_));
    const auto y0 = static_cast<int64_t>(std::floor((y - gate_m) / cell_));
    const auto y1 = static_cast<int64_t>(std::floor((y + gate_m) / cell_));
    double best = gate_m * gate_m;
    int best_id = -1;
    for (int64_t ix = x0; ix <= x1; ++ix) {
        for (int64_t iy = y0; iy <= y1; ++iy) {
            if (!maybeOccupied(ix, iy)) continue;
            const auto it = cells_.find(key(ix, iy));
            if (it == cells_.end()) continue;
            for (int k = it->second.first; k < it->second.second; ++k) {
                const int id = ids_[k];
                const double dx = xy_(id, 0) - x, dy = xy_(id, 1) - y;
                const double d2 = dx * dx + dy * dy;
                if (d2 <= best) {
                    best = d2;
                    best_id = id;
                }
            }
        }
    }
    if (d2_out) *d2_out = best;
    return best_id;
}

}  // namespace forestslam::localization
