#include "forestslam/localization/triangle_star.hpp"

#include <algorithm>
#include <cmath>
#include <set>

#include "forestslam/localization/feature_index.hpp"

namespace forestslam::localization {

Eigen::Vector2d triangleDescriptor(const Eigen::Vector2d &a, const Eigen::Vector2d &b,
                                   const Eigen::Vector2d &c) {
    const double area = 0.5 * std::abs(orient2d(a, b, c));
    const double perimeter = (b - a).norm() + (c - b).norm() + (a - c).norm();
    return {area, perimeter * perimeter};
}

StarFeatures StarSet::features() const {
    StarFeatures f(stars.size(), 8);
    for (size_t i = 0; i < stars.size(); ++i) f.row(i) = stars[i].feature.transpose();
    return f;
}

double edgeLength(const Triangulation &tri, const Eigen::Ref<const Points2> &xy, int t, int k) {
    const auto &v = tri.triangles[t];
    return (xy.row(v[k]) - xy.row(v[(k + 1) % 3])).norm();
}

int shortestEdge(const Triangulation &tri, const Eigen::Ref<const Points2> &xy, int t) {
    int best = 0;
    double best_len = edgeLength(tri, xy, t, 0);
    for (int k = 1; k < 3; ++k) {
        const double len = edgeLength(tri, xy, t, k);
        if (len < best_len) {
            best_len = len;
            best = k;
        }
    }
    return best;
}

bool makeStar(
    const Triangulation &tri, const Eigen::Ref<const Points2> & /*xy*/,
    const Eigen::Ref<const Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>> &descriptors,
    int t, int rotation, Star &star) {
    if (!tri.interior(t)) return false;
    const auto &v = tri.triangles[t];
    star.centre = t;
    star.feature.segment<2>(0) = descriptors.row(t).transpose();
    for (int k = 0; k < 3; ++k) {
        const int e = (rotation + k) % 3;  // edge (v[e], v[e+1]) lies opposite v[e+2]
        const int a = v[e], b = v[(e + 1) % 3];
        const int nb = tri.neighbours[t][(e + 2) % 3];
        int apex = -1;
        for (int w : tri.triangles[nb])
            if (w != a && w != b) apex = w;
        star.vertices[k] = a;
        star.vertices[3 + k] = apex;
        star.feature.segment<2>(2 + 2 * k) = descriptors.row(nb).transpose();
    }
    return true;
}

StarSet buildStars(const Triangulation &tri, const Eigen::Ref<const Points2> &xy) {
    StarSet set;
    set.descriptors.resize(tri.size(), 2);
    for (size_t t = 0; t < tri.size(); ++t) {
        const auto &v = tri.triangles[t];
        set.descriptors.row(t) =
            triangleDescriptor(xy.row(v[0]).transpose(), xy.row(v[1]).transpose(),
                               xy.row(v[2]).transpose())
                .transpose();
    }
    Star star;
    for (size_t t = 0; t < tri.size(); ++t) {
        const int ti = static_cast<int>(t);
        if (makeStar(tri, xy, set.descriptors, ti, shortestEdge(tri, xy, ti), star))
            set.stars.push_back(star);
    }
    return set;
}

Eigen::Vector3d triangleSides(const Eigen::Ref<const Points2> &xy, const std::array<int, 3> &tri,
                              int rotation) {
    Eigen::Vector3d s;
    for (int k = 0; k < 3; ++k)
        s[k] = (xy.row(tri[(rotation + k) % 3]) - xy.row(tri[(rotation + k + 1) % 3])).norm();
    return s;
}

bool canonicalTriangle(const Eigen::Ref<const Points2> &xy, std::array<int, 3> &tri) {
    const Eigen::Vector2d a = xy.row(tri[0]).transpose(), b = xy.row(tri[1]).transpose(),
                          c = xy.row(tri[2]).transpose();
    const double o = orient2d(a, b, c);
    const double scale =
        std::max({(b - a).squaredNorm(), (c - b).squaredNorm(), (a - c).squaredNorm()});
    if (!(std::abs(o) > 1e-6 * scale)) return false;
    if (o < 0) std::swap(tri[1], tri[2]);
    const Eigen::Vector3d s = triangleSides(xy, tri);
    int r = 0;
    for (int k = 1; k < 3; ++k)
        if (s[k] < s[r]) r = k;
    tri = {tri[r], tri[(r + 1) % 3], tri[(r + 2) % 3]};
    return true;
}

std::vector<std::array<int, 3>> neighbourTriangles(const Eigen::Ref<const Points2> &xy,
                                                   const std::vector<int> &rows_in, int k,
                                                   double max_edge) {
    std::vector<int> rows = rows_in;
    if (rows.empty())
        for (Eigen::Index i = 0; i < xy.rows(); ++i)
            if (std::isfinite(xy(i, 0)) && std::isfinite(xy(i, 1))) rows.push_back(int(i));
    std::vector<std::array<int, 3>> out;
    if (rows.size() < 3 || k < 2) return out;
    KdTree::Matrix pts(rows.size(), 2);
    for (size_t i = 0; i < rows.size(); ++i) pts.row(i) = xy.row(rows[i]);
    const KdTree tree(pts);
    std::vector<std::array<int, 3>> keys;
    std::vector<int> idx;
    std::vector<double> dist;
    for (size_t i = 0; i < rows.size(); ++i) {
        tree.knn(pts.row(i).transpose(), k + 1, max_edge, idx, dist);
        for (size_t a = 0; a < idx.size(); ++a) {
            if (idx[a] == int(i)) continue;
            for (size_t b = a + 1; b < idx.size(); ++b) {
                if (idx[b] == int(i)) continue;
                std::array<int, 3> t = {rows[i], rows[idx[a]], rows[idx[b]]};
                if ((xy.row(t[1]) - xy.row(t[2])).norm() > max_edge) continue;
                std::sort(t.begin(), t.end());
                keys.push_back(t);
            }
        }
    }
    std::sort(keys.begin(), keys.end());
    keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
    out.reserve(keys.size());
    for (auto t : keys)
        if (canonicalTriangle(xy, t)) out.push_back(t);
    return out;
}

StarFeature embedFeature(const StarFeature &feature) { return feature.cwiseMax(0.0).cwiseSqrt(); }

}  // namespace forestslam::localization
