#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "forestslam/localization/triangle_star.hpp"

using forestslam::Points2;

TEST(TriangleStar, DescriptorOfKnownTriangle) {
    const auto d = forestslam::localization::triangleDescriptor({0, 0}, {3, 0}, {0, 4});
    EXPECT_DOUBLE_EQ(d[0], 6.0);          // area
    EXPECT_DOUBLE_EQ(d[1], 12.0 * 12.0);  // squared perimeter
}

TEST(TriangleStar, HexagonStarHasCentreAndThreeNeighbours) {
    // A triangle with one extra point beyond each edge: exactly one interior triangle.
    Points2 xy(6, 2);
    xy << 0, 0, 4, 0, 1.5, 3, 2, -2.5, 3.8, 2.6, -1.6, 2.0;
    const auto tri = forestslam::localization::delaunayTriangulation(xy);
    const auto stars = forestslam::localization::buildStars(tri, xy);
    ASSERT_EQ(stars.stars.size(), 1u);
    const auto &s = stars.stars[0];
    // The centre edge v0-v1 is the shortest one, and the apexes are the three outer points.
    const double e01 = (xy.row(s.vertices[0]) - xy.row(s.vertices[1])).norm();
    const double e12 = (xy.row(s.vertices[1]) - xy.row(s.vertices[2])).norm();
    const double e20 = (xy.row(s.vertices[2]) - xy.row(s.vertices[0])).norm();
    EXPECT_LE(e01, e12);
    EXPECT_LE(e01, e20);
    for (int k = 3; k < 6; ++k) EXPECT_GE(s.vertices[k], 3);
    // Feature entries are the descriptors of the triangles they name.
    const auto d0 = forestslam::localization::triangleDescriptor(
        xy.row(0).transpose(), xy.row(1).transpose(), xy.row(2).transpose());
    EXPECT_NEAR(s.feature[0], d0[0], 1e-12);
    EXPECT_NEAR(s.feature[1], d0[1], 1e-12);
    const auto dn = forestslam::localization::triangleDescriptor(xy.row(s.vertices[0]).transpose(),
                                                                 xy.row(s.vertices[1]).transpose(),
                                                                 xy.row(s.vertices[3]).transpose());
    EXPECT_NEAR(s.feature[2], dn[0], 1e-12);
    EXPECT_NEAR(s.feature[3], dn[1], 1e-12);
}

TEST(TriangleStar, FeaturesInvariantToRotationTranslationAndOrder) {
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(0, 60);
    const int n = 120;
    Points2 xy(n, 2);
    for (int i = 0; i < n; ++i) xy.row(i) << u(rng), u(rng);
    const double yaw = 1.1;
    Eigen::Matrix2d R;
    R << std::cos(yaw), -std::sin(yaw), std::sin(yaw), std::cos(yaw);
    std::vector<int> perm(n);
    for (int i = 0; i < n; ++i) perm[i] = i;
    std::shuffle(perm.begin(), perm.end(), rng);
    Points2 moved(n, 2);
    for (int i = 0; i < n; ++i)
        moved.row(i) = (R * xy.row(perm[i]).transpose() + Eigen::Vector2d(-40, 17)).transpose();

    const auto a = forestslam::localization::buildStars(
        forestslam::localization::delaunayTriangulation(xy), xy);
    const auto b = forestslam::localization::buildStars(
        forestslam::localization::delaunayTriangulation(moved), moved);
    ASSERT_EQ(a.stars.size(), b.stars.size());
    ASSERT_GT(a.stars.size(), 100u);
    // Every star of `a` appears in `b` with the same feature and the same (permuted) vertices.
    int found = 0;
    for (const auto &s : a.stars) {
        for (const auto &t : b.stars) {
            bool same = true;
            for (int k = 0; k < 6 && same; ++k) same = perm[t.vertices[k]] == s.vertices[k];
            if (!same) continue;
            EXPECT_LT((s.feature - t.feature).norm(), 1e-8 * (1 + s.feature.norm()));
            ++found;
            break;
        }
    }
    EXPECT_EQ(found, int(a.stars.size()));
}
