#include "forestslam/perception/morphological_ground.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

namespace forestslam::perception {
namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();

// Window half sizes and height thresholds of the iterations, as PCL computes them.
struct Windows {
    std::vector<int> half_sizes;
    std::vector<float> thresholds;
};

Windows windowSchedule(const GroundConfig &opt, float cell) {
    Windows w;
    std::vector<float> window_sizes;
    const auto base = static_cast<float>(opt.base), slope = static_cast<float>(opt.slope);
    const auto d0 = static_cast<float>(opt.initial_distance_m);
    const auto dmax = static_cast<float>(opt.max_distance_m);
    float window = 0.0f;
    for (int it = 0; window < static_cast<float>(opt.max_window_cells); ++it) {
        const int half = opt.exponential ? static_cast<int>(std::pow(base, it))
                                         : static_cast<int>(static_cast<float>(it + 1) * base);
        window = static_cast<float>(2 * half + 1);
        float t = it == 0 ? d0 : slope * (window - window_sizes.back()) * cell + d0;
        w.half_sizes.push_back(half);
        window_sizes.push_back(window);
        w.thresholds.push_back(std::min(t, dmax));
    }
    return w;
}

// Row-major grid of the cells' lowest z (+inf where empty) and each cell's grid index.
struct MinGrid {
    int rows = 0, cols = 0;
    std::vector<float> a;
    std::vector<size_t> at;
};

MinGrid minGrid(const std::vector<Eigen::Vector3f> &cells, float cell) {
    MinGrid g;
    Eigen::Vector3f lo = cells.front(), hi = cells.front();
    for (const auto &p : cells) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
    g.rows = static_cast<int>(std::floor((hi.y() - lo.y()) / cell) + 1);
    g.cols = static_cast<int>(std::floor((hi.x() - lo.x()) / cell) + 1);
    g.a.assign(static_cast<size_t>(g.rows) * static_cast<size_t>(g.cols), kInf);
    g.at.resize(cells.size());
    for (size_t k = 0; k < cells.size(); ++k) {
        const auto r = static_cast<size_t>(std::floor((cells[k].y() - lo.y()) / cell));
        const auto c = static_cast<size_t>(std::floor((cells[k].x() - lo.x()) / cell));
        g.at[k] = r * static_cast<size_t>(g.cols) + c;
        g.a[g.at[k]] = std::min(g.a[g.at[k]], cells[k].z());
    }
    return g;
}

// out(r, c) = op over the clamped (2h+1)^2 window of in, as a row pass into tmp then a column
// pass; out keeps its value where the window holds no cell (`empty`), as PCL's Z and Zf do.
// Both passes run shift by shift over whole rows (contiguous, vectorised). min and max of
// non-NaN values do not depend on the order they are taken in (up to the sign of a zero, which
// no comparison sees), so this is the same grid as a window per cell.
template <class Op>
void windowPass(const std::vector<float> &in, std::vector<float> &out, std::vector<float> &tmp,
                int rows, int cols, int h, float empty, Op op) {
    for (int r = 0; r < rows; ++r) {
        const float *src = in.data() + static_cast<size_t>(r) * cols;
        float *dst = tmp.data() + static_cast<size_t>(r) * cols;
        std::fill(dst, dst + cols, empty);
        for (int d = -h; d <= h; ++d)
            for (int c = std::max(0, -d); c < std::min(cols, cols - d); ++c)
                dst[c] = op(dst[c], src[c + d]);
    }
    std::vector<float> column(static_cast<size_t>(cols));
    float *v = column.data();
    for (int r = 0; r < rows; ++r) {
        std::fill(v, v + cols, empty);
        for (int j = std::max(0, r - h); j <= std::min(rows - 1, r + h); ++j) {
            const float *src = tmp.data() + static_cast<size_t>(j) * cols;
            for (int c = 0; c < cols; ++c) v[c] = op(v[c], src[c]);
        }
        float *dst = out.data() + static_cast<size_t>(r) * cols;
        for (int c = 0; c < cols; ++c)
            if (v[c] != empty) dst[c] = v[c];
    }
}

void replace(std::vector<float> &v, float from, float to) {
    for (float &x : v)
        if (x == from) x = to;
}

}  // namespace

// PCL visits a column-major matrix row by row and takes the full (2h+1)^2 window per cell
// (most of the ground stage); here row and column passes over a row-major grid, same float
// arithmetic, same rules for empty cells.
std::vector<int> morphologicalGround(const std::vector<Eigen::Vector3f> &cells, float cell,
                                     const GroundConfig &opt) {
    if (cells.empty()) return {};
    const Windows w = windowSchedule(opt, cell);
    MinGrid g = minGrid(cells, cell);
    // Empty cells are +inf in the min grids and -inf in the max grids (PCL's NaN is skipped).
    std::vector<float> z(g.a.size(), kInf), zf(g.a.size(), -kInf), tmp(g.a.size());
    auto fmin = [](float x, float y) { return std::min(x, y); };
    auto fmax = [](float x, float y) { return std::max(x, y); };
    std::vector<int> ground(cells.size());
    std::iota(ground.begin(), ground.end(), 0);
    std::vector<int> kept;
    for (size_t i = 0; i < w.half_sizes.size(); ++i) {
        windowPass(g.a, z, tmp, g.rows, g.cols, w.half_sizes[i], kInf, fmin);  // erosion
        replace(z, kInf, -kInf);  // Z's "no cell" is skipped by the dilation, as PCL skips NaN
        windowPass(z, zf, tmp, g.rows, g.cols, w.half_sizes[i], -kInf, fmax);  // dilation
        replace(z, -kInf, kInf);
        kept.clear();
        for (int k : ground)
            if (cells[static_cast<size_t>(k)].z() - zf[g.at[static_cast<size_t>(k)]] <
                w.thresholds[i])
                kept.push_back(k);
        ground.swap(kept);
        // PCL swaps A and Zf: the opened grid is the next input and Zf starts from the old A.
        g.a.swap(zf);
        replace(zf, kInf, -kInf);
        replace(g.a, -kInf, kInf);
    }
    return ground;
}

}  // namespace forestslam::perception
