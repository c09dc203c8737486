#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "forestslam/localization/delaunay.hpp"

using forestslam::Points2;

namespace {

Points2 randomPoints(int n, unsigned seed, double extent = 100.0) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0.0, extent);
    Points2 xy(n, 2);
    for (int i = 0; i < n; ++i) xy.row(i) << u(rng), u(rng);
    return xy;
}

Eigen::Vector2d pt(const Points2 &xy, int i) { return xy.row(i).transpose(); }

double hullArea(const Points2 &xy) {
    std::vector<Eigen::Vector2d> p;
    for (Eigen::Index i = 0; i < xy.rows(); ++i) p.push_back(pt(xy, int(i)));
    std::sort(p.begin(), p.end(),
              [](auto &a, auto &b) { return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y()); });
    std::vector<Eigen::Vector2d> h(2 * p.size());
    size_t k = 0;
    for (size_t i = 0; i < p.size(); ++i) {
        while (k >= 2 && forestslam::localization::orient2d(h[k - 2], h[k - 1], p[i]) <= 0) --k;
        h[k++] = p[i];
    }
    for (size_t i = p.size() - 1, t = k + 1; i > 0; --i) {
        while (k >= t && forestslam::localization::orient2d(h[k - 2], h[k - 1], p[i - 1]) <= 0) --k;
        h[k++] = p[i - 1];
    }
    h.resize(k - 1);
    double area = 0;
    for (size_t i = 0; i < h.size(); ++i) {
        const auto &a = h[i], &b = h[(i + 1) % h.size()];
        area += a.x() * b.y() - b.x() * a.y();
    }
    return 0.5 * area;
}

// Checks counter-clockwise triangles, symmetric adjacency and the empty-circumcircle property.
void checkDelaunay(const Points2 &xy, const forestslam::localization::Triangulation &tri) {
    for (size_t t = 0; t < tri.size(); ++t) {
        const auto &v = tri.triangles[t];
        const Eigen::Vector2d a = pt(xy, v[0]), b = pt(xy, v[1]), c = pt(xy, v[2]);
        ASSERT_GT(forestslam::localization::orient2d(a, b, c), 0.0)
            << "triangle " << t << " not ccw";
        for (int k = 0; k < 3; ++k) {
            const int nb = tri.neighbours[t][k];
            if (nb < 0) continue;
            const auto &nv = tri.neighbours[nb];
            EXPECT_TRUE(nv[0] == int(t) || nv[1] == int(t) || nv[2] == int(t));
            // The neighbour shares exactly the edge opposite v[k].
            const auto &w = tri.triangles[nb];
            const int e0 = v[(k + 1) % 3], e1 = v[(k + 2) % 3];
            EXPECT_TRUE(std::count(w.begin(), w.end(), e0) == 1 &&
                        std::count(w.begin(), w.end(), e1) == 1);
        }
        // Circle test with a relative tolerance: no input point strictly inside.
        const double scale = std::pow((b - a).norm() * (c - b).norm() * (a - c).norm(), 4.0 / 3.0);
        for (Eigen::Index i = 0; i < xy.rows(); ++i) {
            if (i == v[0] || i == v[1] || i == v[2]) continue;
            ASSERT_LE(forestslam::localization::inCircle(a, b, c, pt(xy, int(i))), 1e-9 * scale)
                << "point " << i << " inside circumcircle of triangle " << t;
        }
    }
}

double totalArea(const Points2 &xy, const forestslam::localization::Triangulation &tri) {
    double area = 0;
    for (const auto &v : tri.triangles)
        area += 0.5 * forestslam::localization::orient2d(pt(xy, v[0]), pt(xy, v[1]), pt(xy, v[2]));
    return area;
}

}  // namespace

TEST(Delaunay, RandomPointsEmptyCircumcircleAndConvexHull) {
    for (unsigned seed : {1u, 2u, 3u}) {
        const Points2 xy = randomPoints(400, seed);
        const auto tri = forestslam::localization::delaunayTriangulation(xy);
        checkDelaunay(xy, tri);
        EXPECT_EQ(tri.used_points.size(), 400u);
        EXPECT_NEAR(totalArea(xy, tri), hullArea(xy), 1e-6 * hullArea(xy));
        // Euler: T = 2n - 2 - h.
        int hull_edges = 0;
        for (const auto &n : tri.neighbours)
            hull_edges += int(n[0] < 0) + int(n[1] < 0) + int(n[2] < 0);
        EXPECT_EQ(int(tri.size()), 2 * 400 - 2 - hull_edges);
    }
}

TEST(Delaunay, RegularGridWithCocircularPoints) {
    Points2 xy(100, 2);
    for (int i = 0; i < 100; ++i) xy.row(i) << i % 10, i / 10;
    const auto tri = forestslam::localization::delaunayTriangulation(xy);
    checkDelaunay(xy, tri);
    EXPECT_EQ(tri.size(), 162u);  // 2 per grid cell
    EXPECT_NEAR(totalArea(xy, tri), 81.0, 1e-9);
}

TEST(Delaunay, FarFromOriginLikeProjectedCoordinates) {
    Points2 xy = randomPoints(200, 7, 50.0);
    xy.col(0).array() += 500000.0;
    xy.col(1).array() += 6700000.0;
    const auto tri = forestslam::localization::delaunayTriangulation(xy);
    checkDelaunay(xy, tri);
    EXPECT_NEAR(totalArea(xy, tri), hullArea(xy), 1e-6 * hullArea(xy));
}

TEST(Delaunay, DegenerateInputsGiveEmptyOrReducedResults) {
    EXPECT_EQ(forestslam::localization::delaunayTriangulation(Points2(0, 2)).size(), 0u);
    Points2 two(2, 2);
    two << 0, 0, 1, 1;
    EXPECT_EQ(forestslam::localization::delaunayTriangulation(two).size(), 0u);
    Points2 line(10, 2);
    for (int i = 0; i < 10; ++i) line.row(i) << i, 2.0 * i;
    const auto collinear = forestslam::localization::delaunayTriangulation(line);
    EXPECT_EQ(collinear.size(), 0u);
    EXPECT_TRUE(collinear.used_points.empty());
    Points2 same(5, 2);
    same.setConstant(3.0);
    EXPECT_EQ(forestslam::localization::delaunayTriangulation(same).size(), 0u);

    // Duplicates and NaN rows are skipped; the rest triangulates.
    Points2 xy = randomPoints(50, 11);
    Points2 with_dups(53, 2);
    with_dups << xy, xy.row(3), xy.row(10), Eigen::RowVector2d(NAN, 1.0);
    const auto tri = forestslam::localization::delaunayTriangulation(with_dups);
    EXPECT_EQ(tri.used_points.size(), 50u);
    checkDelaunay(xy, forestslam::localization::delaunayTriangulation(xy));
    EXPECT_EQ(tri.size(), forestslam::localization::delaunayTriangulation(xy).size());
    for (const auto &v : tri.triangles)
        for (int i : v) EXPECT_LT(i, 50);
}
