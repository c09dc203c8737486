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
        // Built over a contiguous copy of (point, row) entries: the partitions then read and
        // move whole entries instead of gathering strided matrix rows through the row ids. The
        // comparisons are the same as on the ids, so the tree (and every query's order) is too.
        std::vector<Entry> work(ids_.size());
        for (size_t k = 0; k < ids_.size(); ++k)
            work[k] = {{points(ids_[k], 0), points(ids_[k], 1), points(ids_[k], 2)}, ids_[k]};
        nodes_.reserve(2 * ids_.size() / kLeaf + 2);
        buildNode(work, 0, static_cast<int>(work.size()));
        pts_.resize(work.size());
        for (size_t k = 0; k < work.size(); ++k) {
            pts_[k] = work[k].p;
            ids_[k] = work[k].row;
        }
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

    struct Entry {
        std::array<double, 3> p;
        int row;
    };

    int buildNode(std::vector<Entry> &work, int begin, int end) {
        const int id = static_cast<int>(nodes_.size());
        nodes_.emplace_back();
        nodes_[static_cast<size_t>(id)].begin = begin;
        nodes_[static_cast<size_t>(id)].end = end;
        if (end - begin <= kLeaf) return id;
        std::array<double, 3> lo, hi;
        lo.fill(std::numeric_limits<double>::max());
        hi.fill(-std::numeric_limits<double>::max());
        for (int k = begin; k < end; ++k) {
            const auto &p = work[static_cast<size_t>(k)].p;
            for (size_t a = 0; a < 3; ++a) {
                lo[a] = std::min(lo[a], p[a]);
                hi[a] = std::max(hi[a], p[a]);
            }
        }
        int axis = 0;  // the widest extent, the first on a tie (as Eigen's maxCoeff)
        for (int a = 1; a < 3; ++a)
            if (hi[a] - lo[a] > hi[axis] - lo[axis]) axis = a;
        const int mid = begin + (end - begin) / 2;
        std::nth_element(work.begin() + begin, work.begin() + mid, work.begin() + end,
                         [axis](const Entry &a, const Entry &b) { return a.p[axis] < b.p[axis]; });
        const double split = work[static_cast<size_t>(mid)].p[static_cast<size_t>(axis)];
        const int left = buildNode(work, begin, mid);
        const int right = buildNode(work, mid, end);
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
