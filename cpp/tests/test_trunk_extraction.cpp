#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "forestslam/localization/trunk_extraction.hpp"

TEST(TrunkExtraction, FindsVerticalStemsAboveGround) {
    std::mt19937 rng(1);
    std::uniform_real_distribution<double> u(0, 1);
    std::vector<Eigen::Vector3d> pts;
    // Ground: a slightly rough plane.
    for (double x = 0; x < 30; x += 0.2)
        for (double y = 0; y < 30; y += 0.2) pts.emplace_back(x, y, 0.02 * u(rng));
    // Five stems of radius 0.15 m, 4 m tall.
    const std::vector<Eigen::Vector2d> centres = {{5, 5}, {12, 20}, {25, 8}, {18, 14}, {7, 26}};
    for (const auto &c : centres)
        for (double z = 0; z < 4; z += 0.05)
            for (int k = 0; k < 24; ++k) {
                const double a = 2 * M_PI * k / 24;
                pts.emplace_back(c.x() + 0.15 * std::cos(a), c.y() + 0.15 * std::sin(a), z);
            }
    // A crown: dense foliage well above the search band (vertical structure, but no stem).
    for (int k = 0; k < 4000; ++k)
        pts.emplace_back(22 + 2 * u(rng), 22 + 2 * u(rng), 5 + 3 * u(rng));
    // Low shrub clutter: no structure 1 m above it.
    for (int k = 0; k < 300; ++k) pts.emplace_back(20 + u(rng), 25 + u(rng), 0.5 * u(rng));
    forestslam::Points3 cloud(pts.size(), 3);
    for (size_t i = 0; i < pts.size(); ++i) cloud.row(i) = pts[i].transpose();

    const auto trunks = forestslam::localization::extractTrunks(cloud);
    ASSERT_EQ(trunks.xy.rows(), 5);
    for (const auto &c : centres) {
        double best = 1e9;
        for (Eigen::Index i = 0; i < trunks.xy.rows(); ++i)
            best = std::min(best, (trunks.xy.row(i).transpose() - c).norm());
        EXPECT_LT(best, 0.05);
    }
}

TEST(TrunkExtraction, EmptyAndNonFiniteInputs) {
    EXPECT_EQ(forestslam::localization::extractTrunks(forestslam::Points3(0, 3)).xy.rows(), 0);
    forestslam::Points3 nan(3, 3);
    nan.setConstant(NAN);
    EXPECT_EQ(forestslam::localization::extractTrunks(nan).xy.rows(), 0);
}
