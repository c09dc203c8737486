#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>

#include "forestslam/perception/detector.hpp"
#include "perception_scene.hpp"

using namespace forestslam;
using namespace forestslam::perception;

TEST(Detector, FindsEveryVisibleStemWithItsDiameter) {
    const std::vector<test::Tree> trees{{4, 1, 0.3}, {-6, 3, 0.4}, {2, -7, 0.25}, {-3, -9, 0.35}};
    const auto scan = test::castScan(trees, 1.8, 0.01, 5);
    const Detection det = detectStems(scan.points, Eigen::VectorXd(), scan.ring,
                                      test::vlp16Geometry(), true, PerceptionConfig{});
    ASSERT_EQ(det.stems.size(), trees.size());
    for (const auto &t : trees) {
        double best = 1e9;
        const Stem *match = nullptr;
        for (const Stem &s : det.stems) {
            const double d = std::hypot(s.breast.x() - t.x, s.breast.y() - t.y);
            if (d < best) best = d, match = &s;
        }
        EXPECT_LT(best, 0.1);
        EXPECT_NEAR(match->diameter.dbh, t.dbh, 0.04);
        EXPECT_NEAR(match->base_z, -1.8, 0.1);
        EXPECT_NEAR(match->breast.z(), -0.5, 0.1);
        EXPECT_GT(match->shape.axis.z(), 0.95);
    }
    EXPECT_GT(det.ground.rows(), 100);
    EXPECT_GT(det.up.z(), 0.99);
    for (const char *stage :
         {"intensity", "ground", "normals", "clustering", "classification", "diameter", "total"})
        EXPECT_EQ(det.timing_ms.count(stage), 1u) << stage;
}

TEST(Detector, BadInputGivesEmptyResults) {
    const auto g = test::vlp16Geometry();
    const PerceptionConfig o;
    const Eigen::VectorXd no_i;
    const Eigen::VectorXi no_r;
    EXPECT_TRUE(detectStems(Points3(0, 3), no_i, no_r, g, true, o).stems.empty());
    Points3 nan(100, 3);
    nan.setConstant(std::numeric_limits<double>::quiet_NaN());
    EXPECT_TRUE(detectStems(nan, no_i, no_r, g, true, o).stems.empty());
    Points3 one(1, 3);
    one << 1, 2, 3;
    EXPECT_TRUE(detectStems(one, no_i, no_r, g, true, o).stems.empty());
    // Ring values outside the image are skipped, not a crash.
    const auto scan = test::castScan({{4, 1, 0.3}}, 1.8, 0.0, 1);
    Eigen::VectorXi bad = Eigen::VectorXi::Constant(scan.points.rows(), 99);
    EXPECT_TRUE(detectStems(scan.points, no_i, bad, g, true, o).stems.empty());
    // The same scan as a map (3D clustering, fixed-radius normals) still finds the stem.
    EXPECT_EQ(detectStems(scan.points, no_i, no_r, g, false, o).stems.size(), 1u);
}

TEST(Detector, PerPointFieldsOfAnotherLengthThrow) {
    const auto g = test::vlp16Geometry();
    const Points3 points = Points3::Zero(10, 3);
    // One intensity or ring short: an error, not a silently unfiltered or ring-less scan.
    EXPECT_THROW(detectStems(points, Eigen::VectorXd::Zero(9), Eigen::VectorXi(), g, true, {}),
                 std::invalid_argument);
    EXPECT_THROW(detectStems(points, Eigen::VectorXd(), Eigen::VectorXi::Zero(9), g, true, {}),
                 std::invalid_argument);
}
