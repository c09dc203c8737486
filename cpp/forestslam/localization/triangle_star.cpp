#include "forestslam/localization/triangle_star.hpp"

#include <cmath>

namespace forestslam {

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

bool makeStar(const Triangulation &tri, const Eigen::Ref<const Points2> &/*xy*/,
              const Eigen::Ref<const Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>>
                  &descriptors,
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
        set.descriptors.row(t) = triangleDescriptor(xy.row(v[0]).transpose(),
                                                    xy.row(v[1]).transpose(),
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

StarFeature embedFeature(const StarFeature &feature) {
    return feature.cwiseMax(0.0).cwiseSqrt();
}

}  // namespace forestslam
