#include "forestslam/localization/delaunay.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

namespace forestslam::localization {
namespace {

using Real = long double;  // extra mantissa for predicates that involve the far super vertices

struct P {
    Real x, y;
};

Real orient(const P &a, const P &b, const P &c) {
    return (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
}

Real incircle(const P &a, const P &b, const P &c, const P &d) {
    const Real adx = a.x - d.x, ady = a.y - d.y;
    const Real bdx = b.x - d.x, bdy = b.y - d.y;
    const Real cdx = c.x - d.x, cdy = c.y - d.y;
    const Real ad = adx * adx + ady * ady;
    const Real bd = bdx * bdx + bdy * bdy;
    const Real cd = cdx * cdx + cdy * cdy;
    return ad * (bdx * cdy - cdx * bdy) + bd * (cdx * ady - adx * cdy) +
           cd * (adx * bdy - bdx * ady);
}

// Position along a Hilbert curve of a point on a 2^16 x 2^16 grid: inserting in this order keeps
// consecutive points close, so the point-location walk is short.
uint64_t hilbertIndex(uint32_t x, uint32_t y) {
    const uint32_t n = 1u << 16;
    uint64_t d = 0;
    for (uint32_t s = n / 2; s > 0; s /= 2) {
        const uint32_t rx = (x & s) ? 1 : 0;
        const uint32_t ry = (y & s) ? 1 : 0;
        d += static_cast<uint64_t>(s) * s * ((3 * rx) ^ ry);
        if (ry == 0) {
            if (rx == 1) {
                x = n - 1 - x;
                y = n - 1 - y;
            }
            std::swap(x, y);
        }
    }
    return d;
}

class Builder {
  public:
    explicit Builder(std::vector<P> pts) : p_(std::move(pts)) {}

    // Triangulate p_[0..n) (normalized to about [-0.5, 0.5]^2); returns the skipped duplicates.
    std::vector<bool> run(const std::vector<int> &order, Real dup_tol2) {
        const int n = static_cast<int>(p_.size());
        const Real K = 1000;  // super triangle far outside the unit box
        p_.push_back({-K, -K});
        p_.push_back({K, -K});
        p_.push_back({0, K});
        V_.push_back({n, n + 1, n + 2});
        N_.push_back({-1, -1, -1});
        std::vector<bool> skipped(n, false);
        int last = 0;
        for (int idx : order) {
            int t = locate(idx, last);
            if (nearVertex(t, idx, dup_tol2)) {
                skipped[idx] = true;
                continue;
            }
            last = insert(t, idx);
        }
        return skipped;
    }

    std::vector<std::array<int, 3>> V_, N_;

  private:
    std::vector<P> p_;
    std::vector<std::pair<int, int>> stack_;
    uint32_t rng_ = 12345;

    bool nearVertex(int t, int idx, Real tol2) const {
        auto close = [&](int tri) {
            for (int v : V_[tri]) {
                const Real dx = p_[v].x - p_[idx].x, dy = p_[v].y - p_[idx].y;
                if (dx * dx + dy * dy <= tol2) return true;
            }
            return false;
        };
        if (close(t)) return true;
        for (int nb : N_[t])
            if (nb >= 0 && close(nb)) return true;
        return false;
    }

    // Visibility walk from triangle `start` to the triangle that contains point idx.
    int locate(int idx, int start) {
        const P &q = p_[idx];
        int t = start;
        const size_t max_steps = 4 * V_.size() + 16;
        for (size_t step = 0; step < max_steps; ++step) {
            rng_ = rng_ * 1664525u + 1013904223u;
            const int r = static_cast<int>((rng_ >> 16) % 3);  // random start edge avoids cycles
            bool moved = false;
            for (int k = 0; k < 3; ++k) {
                const int i = (r + k) % 3;
                const auto &v = V_[t];
                if (orient(p_[v[(i + 1) % 3]], p_[v[(i + 2) % 3]], q) < 0 && N_[t][i] >= 0) {
                    t = N_[t][i];
                    moved = true;
                    break;
                }
            }
            if (!moved) return t;
        }
        // Fallback (never expected): exhaustive search.
        for (size_t s = 0; s < V_.size(); ++s) {
            const auto &v = V_[s];
            if (orient(p_[v[0]], p_[v[1]], q) >= 0 && orient(p_[v[1]], p_[v[2]], q) >= 0 &&
                orient(p_[v[2]], p_[v[0]], q) >= 0)
                return static_cast<int>(s);
        }
        return t;
    }

    void replaceNeighbour(int tri, int old_nb, int new_nb) {
        if (tri < 0) return;
        for (int &x : N_[tri])
            if (x == old_nb) {
                x = new_nb;
                return;
            }
    }

    // Split triangle t at point idx into three, then restore the Delaunay property by flips.
    int insert(int t, int idx) {
        const auto v = V_[t];
        const auto nb = N_[t];
        const int a = v[0], b = v[1], c = v[2];
        const int t0 = t;
        const int t1 = static_cast<int>(V_.size());
        const int t2 = t1 + 1;
        V_[t0] = {a, b, idx};
        N_[t0] = {t1, t2, nb[2]};
        V_.push_back({b, c, idx});
        N_.push_back({t2, t0, nb[0]});
        V_.push_back({c, a, idx});
        N_.push_back({t0, t1, nb[1]});
        replaceNeighbour(nb[0], t, t1);
        replaceNeighbour(nb[1], t, t2);
        stack_.clear();
        stack_.push_back({t0, 2});
        stack_.push_back({t1, 2});
        stack_.push_back({t2, 2});
        while (!stack_.empty()) {
            auto [tri, i] = stack_.back();
            stack_.pop_back();
            legalize(tri, i);
        }
        return t0;
    }

    // Edge opposite V_[t][i] (the new point): flip when the apex across it is in t's circle.
    void legalize(int t, int i) {
        const int o = N_[t][i];
        if (o < 0) return;
        int j = 0;
        while (j < 3 && N_[o][j] != t) ++j;
        if (j == 3) return;
        const int p = V_[t][i], q = V_[t][(i + 1) % 3], r = V_[t][(i + 2) % 3];
        const int d = V_[o][j];
        if (incircle(p_[p], p_[q], p_[r], p_[d]) <= 0) return;
        const int A = N_[t][(i + 1) % 3];  // across (r, p)
        const int B = N_[t][(i + 2) % 3];  // across (p, q)
        const int C = N_[o][(j + 1) % 3];  // across (q, d)
        const int D = N_[o][(j + 2) % 3];  // across (d, r)
        V_[t] = {p, q, d};
        N_[t] = {C, o, B};
        V_[o] = {p, d, r};
        N_[o] = {D, A, t};
        replaceNeighbour(C, o, t);
        replaceNeighbour(A, t, o);
        stack_.push_back({t, 0});
        stack_.push_back({o, 0});
    }
};

}  // namespace

double orient2d(const Eigen::Vector2d &a, const Eigen::Vector2d &b, const Eigen::Vector2d &c) {
    return static_cast<double>(orient({a.x(), a.y()}, {b.x(), b.y()}, {c.x(), c.y()}));
}

double inCircle(const Eigen::Vector2d &a, const Eigen::Vector2d &b, const Eigen::Vector2d &c,
                const Eigen::Vector2d &d) {
    return static_cast<double>(
        incircle({a.x(), a.y()}, {b.x(), b.y()}, {c.x(), c.y()}, {d.x(), d.y()}));
}

Triangulation delaunayTriangulation(const Eigen::Ref<const Points2> &xy,
                                    double duplicate_tolerance) {
    Triangulation out;
    std::vector<int> finite;
    finite.reserve(xy.rows());
    for (Eigen::Index i = 0; i < xy.rows(); ++i)
        if (std::isfinite(xy(i, 0)) && std::isfinite(xy(i, 1))) finite.push_back(int(i));
    if (finite.size() < 3) return out;

    double xmin = std::numeric_limits<double>::max(), ymin = xmin;
    double xmax = std::numeric_limits<double>::lowest(), ymax = xmax;
    for (int i : finite) {
        xmin = std::min(xmin, xy(i, 0));
        xmax = std::max(xmax, xy(i, 0));
        ymin = std::min(ymin, xy(i, 1));
        ymax = std::max(ymax, xy(i, 1));
    }
    const double scale = std::max(xmax - xmin, ymax - ymin);
    if (!(scale > 0) || !std::isfinite(scale)) return out;
    const double cx = 0.5 * (xmin + xmax), cy = 0.5 * (ymin + ymax);

    const int n = static_cast<int>(finite.size());
    std::vector<P> pts(n);
    std::vector<std::pair<uint64_t, int>> keys(n);
    for (int k = 0; k < n; ++k) {
        const int i = finite[k];
        pts[k] = {(xy(i, 0) - cx) / scale, (xy(i, 1) - cy) / scale};
        const auto gx =
            static_cast<uint32_t>(std::clamp((pts[k].x + 0.5) * 65535.0L, 0.0L, 65535.0L));
        const auto gy =
            static_cast<uint32_t>(std::clamp((pts[k].y + 0.5) * 65535.0L, 0.0L, 65535.0L));
        keys[k] = {hilbertIndex(gx, gy), k};
    }
    std::sort(keys.begin(), keys.end());
    std::vector<int> order(n);
    for (int k = 0; k < n; ++k) order[k] = keys[k].second;

    const Real tol = std::max(duplicate_tolerance, 0.0) / scale;
    Builder builder(std::move(pts));
    const std::vector<bool> skipped = builder.run(order, std::max(tol * tol, Real(1e-24)));

    // Drop triangles on the super vertices and renumber.
    const int m = static_cast<int>(builder.V_.size());
    std::vector<int> new_id(m, -1);
    int count = 0;
    for (int t = 0; t < m; ++t) {
        const auto &v = builder.V_[t];
        if (v[0] < n && v[1] < n && v[2] < n) new_id[t] = count++;
    }
    out.triangles.reserve(count);
    out.neighbours.reserve(count);
    for (int t = 0; t < m; ++t) {
        if (new_id[t] < 0) continue;
        const auto &v = builder.V_[t];
        const auto &nb = builder.N_[t];
        out.triangles.push_back({finite[v[0]], finite[v[1]], finite[v[2]]});
        out.neighbours.push_back({nb[0] >= 0 ? new_id[nb[0]] : -1, nb[1] >= 0 ? new_id[nb[1]] : -1,
                                  nb[2] >= 0 ? new_id[nb[2]] : -1});
    }
    for (int k = 0; k < n; ++k)
        if (!skipped[k]) out.used_points.push_back(finite[k]);
    std::sort(out.used_points.begin(), out.used_points.end());
    // Collinear input leaves only slivers: nothing real to return.
    double max_area2 = 0;
    for (const auto &t : out.triangles) {
        const Eigen::Vector2d a = xy.row(t[0]).transpose(), b = xy.row(t[1]).transpose(),
                              c = xy.row(t[2]).transpose();
        max_area2 = std::max(max_area2, std::abs(orient2d(a, b, c)));
    }
    if (max_area2 <= 1e-12 * scale * scale) {
        out = Triangulation{};
    }
    return out;
}

}  // namespace forestslam::localization
