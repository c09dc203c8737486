// Static 3-D k-d tree with leaf buckets over a subset of rows of a point matrix: exact nearest
// and k-nearest queries, bounded by a maximum distance (ICP gates its correspondences and the
// normal filter searches a radius, so most of the tree is pruned). Double precision; points are
// copied in tree order for cache-friendly leaves. Header-only. Written for the per-scan hot
// paths instead of PCL's KdTreeFLANN, whose per-query overhead dominated them.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam {

class KdTree3 {
  public:
    void build(const Eigen::Ref<const Points3> &points, std::vector<int> rows) {
        ids_ = std::move(rows);
        nodes_.clear();
        pts_.clear();
        if (ids_.empty()) return;
        nodes_.reserve(2 * ids_.size() / kLeaf + 2);
        buildNode(points, 0, static_cast<int>(ids_.size()));
        pts_.resize(ids_.size());
        for (size_t k = 0; k < ids_.size(); ++k)
            pts_[k] = {points(ids_[k], 0), points(ids_[k], 1), points(ids_[k], 2)};
    }

    bool empty() const { return ids_.empty(); }

    // Row of the nearest point within sqrt(max_d2) of q (-1 if none) and its squared distance.
    int nearest(const Eigen::Vector3d &q, double max_d2, double &d2) const {
        if (ids_.empty()) return -1;
        const std::array<double, 3> qa{q.x(), q.y(), q.z()};
        double best = max_d2;
        int best_k = -1;
        nearestIn(0, qa, best, best_k);
        if (best_k < 0) return -1;
        d2 = best;
        return ids_[static_cast<size_t>(best_k)];
    }

    // The (up to) k nearest points within sqrt(max_d2) of q as (squared distance, row) pairs in
    // `out` (in no order; `out` is reused to avoid allocations); returns how many.
    int knn(const Eigen::Vector3d &q, int k, double max_d2,
            std::vector<std::pair<double, int>> &out) const {
        out.clear();
        if (ids_.empty() || k <= 0) return 0;
        const std::array<double, 3> qa{q.x(), q.y(), q.z()};
        if (std::isfinite(max_d2)) {
            Buffer b{out, static_cast<size_t>(k), max_d2};
            knnIn(0, qa, b);
            b.finish();
        } else {
            Heap h{out, static_cast<size_t>(k), max_d2};
            knnIn(0, qa, h);
        }
        for (auto &item : out) item.second = ids_[static_cast<size_t>(item.second)];
        return static_cast<int>(out.size());
    }

  private:
    static constexpr int kLeaf = 8;
    struct Node {
        double split = 0;
        int axis = -1;  // -1: leaf over [begin, end)
        int begin = 0, end = 0;
        int left = -1, right = -1;
    };
    // Max-heap (by distance) of the k best candidates; `bound` is the k-th distance once full
    // (the gate before).
    struct Heap {
        std::vector<std::pair<double, int>> &items;
        size_t k;
        double bound;
        void push(double dd, int idx) {
            if (items.size() < k) {
                items.emplace_back(dd, idx);
                std::push_heap(items.begin(), items.end());
                if (items.size() == k) bound = std::min(bound, items.front().first);
                return;
            }
            if (!(dd < items.front().first)) return;
            std::pop_heap(items.begin(), items.end());
            items.back() = {dd, idx};
            std::push_heap(items.begin(), items.end());
            bound = std::min(bound, items.front().first);
        }
        void finish() {}
    };
    // The k best candidates within a radius: collected unordered and cut back to the k nearest
    // (nth_element) whenever 2k have gathered, `bound` then the k-th distance. Within a radius
    // most candidates are kept, and this costs less than a heap update per candidate (the
    // normal filter's radius searches: -20 % CPU); without one the heap prunes sooner.
    struct Buffer {
        std::vector<std::pair<double, int>> &items;
        size_t k;
        double bound;
        void push(double dd, int idx) {
            items.emplace_back(dd, idx);
            if (items.size() >= 2 * k) finish();
        }
        void finish() {
            if (items.size() <= k) return;
            std::nth_element(items.begin(), items.begin() + static_cast<long>(k - 1), items.end());
            items.resize(k);
            bound = std::min(bound, items[k - 1].first);
        }
    };

    int buildNode(const Eigen::Ref<const Points3> &points, int begin, int end) {
        const int id = static_cast<int>(nodes_.size());
        nodes_.emplace_back();
        nodes_[static_cast<size_t>(id)].begin = begin;
        nodes_[static_cast<size_t>(id)].end = end;
        if (end - begin <= kLeaf) return id;
        Eigen::Array3d lo = Eigen::Array3d::Constant(std::numeric_limits<double>::max());
        Eigen::Array3d hi = -lo;
        for (int k = begin; k < end; ++k) {
            const Eigen::Array3d p = points.row(ids_[static_cast<size_t>(k)]).transpose().array();
            lo = lo.min(p);
            hi = hi.max(p);
        }
        int axis = 0;
        (hi - lo).maxCoeff(&axis);
        const int mid = begin + (end - begin) / 2;
        std::nth_element(ids_.begin() + begin, ids_.begin() + mid, ids_.begin() + end,
                         [&](int a, int b) { return points(a, axis) < points(b, axis); });
        const double split = points(ids_[static_cast<size_t>(mid)], axis);
        const int left = buildNode(points, begin, mid);
        const int right = buildNode(points, mid, end);
        Node &n = nodes_[static_cast<size_t>(id)];
        n.axis = axis;
        n.split = split;
        n.left = left;
        n.right = right;
        return id;
    }

    static double dist2(const std::array<double, 3> &a, const std::array<double, 3> &b) {
        const double dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
        return dx * dx + dy * dy + dz * dz;
    }

    void nearestIn(int id, const std::array<double, 3> &q, double &best, int &best_k) const {
        const Node &n = nodes_[static_cast<size_t>(id)];
        if (n.axis < 0) {
            for (int k = n.begin; k < n.end; ++k) {
                const double dd = dist2(pts_[static_cast<size_t>(k)], q);
                if (dd <= best) best = dd, best_k = k;
            }
            return;
        }
        const double diff = q[static_cast<size_t>(n.axis)] - n.split;
        nearestIn(diff < 0 ? n.left : n.right, q, best, best_k);
        if (diff * diff <= best) nearestIn(diff < 0 ? n.right : n.left, q, best, best_k);
    }

    template <class Best>
    void knnIn(int id, const std::array<double, 3> &q, Best &h) const {
        const Node &n = nodes_[static_cast<size_t>(id)];
        if (n.axis < 0) {
            for (int k = n.begin; k < n.end; ++k) {
                const double dd = dist2(pts_[static_cast<size_t>(k)], q);
                if (dd <= h.bound) h.push(dd, k);
            }
            return;
        }
        const double diff = q[static_cast<size_t>(n.axis)] - n.split;
        knnIn(diff < 0 ? n.left : n.right, q, h);
        if (diff * diff <= h.bound) knnIn(diff < 0 ? n.right : n.left, q, h);
    }

    std::vector<int> ids_;
    std::vector<std::array<double, 3>> pts_;
    std::vector<Node> nodes_;
};

}  // namespace forestslam
