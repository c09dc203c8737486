#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>

#include "forestslam/perception/preprocess.hpp"
#include "perception_scene.hpp"

using namespace forestslam;
using namespace forestslam::perception;

TEST(Preprocess, IntensityFilterDropsBrightAndIsSkippedWithoutThreshold) {
    Eigen::VectorXd in(4);
    in << 10, 200, std::numeric_limits<double>::quiet_NaN(), 100;
    EXPECT_EQ(intensityFilter(in, 100.0, 4), (std::vector<int>{0, 3}));
    EXPECT_EQ(intensityFilter(in, std::numeric_limits<double>::quiet_NaN(), 4).size(), 4u);
    EXPECT_EQ(intensityFilter(Eigen::VectorXd(), 100.0, 3).size(), 3u);  // no intensity
}

TEST(Preprocess, GroundIsThePlaneNotTheStems) {
    const auto scan = test::castScan({{4, 1, 0.3}, {-6, 3, 0.4}, {2, -7, 0.25}}, 1.8, 0.01, 1);
    const GroundSegmentation gs = segmentGround(scan.points, GroundConfig{});
    int plane = 0, plane_ground = 0, stem = 0, stem_ground = 0;
    for (Eigen::Index i = 0; i < scan.points.rows(); ++i) {
        const double z = scan.points(i, 2);
        if (std::hypot(scan.points(i, 0), scan.points(i, 1)) > 30) continue;
        if (z < -1.75) plane++, plane_ground += gs.is_ground[i];
        if (z > -1.8 + 0.4) stem++, stem_ground += gs.is_ground[i];
    }
    ASSERT_GT(plane, 1000);
    ASSERT_GT(stem, 50);
    EXPECT_GT(static_cast<double>(plane_ground) / plane, 0.97);
    EXPECT_EQ(stem_ground, 0);
    EXPECT_NEAR(gs.grid.heightAt(10.0, 3.0), -1.8, 0.05);
    EXPECT_TRUE(std::isnan(gs.grid.heightAt(0.0, 0.0)));  // blind circle: unknown
}

TEST(Preprocess, GroundOfEmptyOrTinyInputIsEmpty) {
    EXPECT_EQ(segmentGround(Points3(0, 3), GroundConfig{}).ground_count, 0);
    Points3 one(1, 3);
    one << 1, 2, 3;
    EXPECT_EQ(segmentGround(one, GroundConfig{}).ground_count, 0);
}

TEST(Preprocess, ThinGroundKeepsOnePointPerVoxel) {
    Points3 p(4, 3);
    p << 0.01, 0.01, 0.0, 0.02, 0.02, 0.01, 1.0, 1.0, 0.0, 5.0, 5.0, 5.0;
    const Points3 g = thinGround(p, {1, 1, 1, 0}, 0.25);
    ASSERT_EQ(g.rows(), 2);
    EXPECT_DOUBLE_EQ(g(0, 2), 0.0);  // the lowest of the first voxel
}

TEST(Preprocess, AdaptiveNormalFilterKeepsStemsAndDropsGround) {
    // Stems at 4 m and 16 m: the far one is hit by rings 0.56 m apart.
    const auto scan = test::castScan({{4, 0, 0.3}, {0, 16, 0.4}}, 1.8, 0.0, 2);
    std::vector<int> all(static_cast<size_t>(scan.points.rows()));
    for (size_t i = 0; i < all.size(); ++i) all[i] = static_cast<int>(i);
    NormalFilterConfig o;
    const auto res = normalFilter(scan.points, all, 2.0 * M_PI / 180, o, nullptr);
    int near = 0, far = 0, ground = 0;
    for (size_t k = 0; k < res.kept.size(); ++k) {
        const auto p = scan.points.row(res.kept[k]);
        EXPECT_LT(std::abs(res.normals(static_cast<Eigen::Index>(k), 2)), 0.5 + 1e-6);
        if (p.z() < -1.75)
            ground++;
        else if (std::hypot(p.x() - 4, p.y()) < 0.3)
            near++;
        else if (std::hypot(p.x(), p.y() - 16) < 0.4)
            far++;
    }
    EXPECT_EQ(ground, 0);
    EXPECT_GT(near, 30);
    EXPECT_GT(far, 10);
    ASSERT_EQ(res.radius_per_ring.size(), 11u);
    EXPECT_LT(res.radius_per_ring.front(), res.radius_per_ring.back());
    // Fixed small radius (the ablation): the far stem's rings never meet, it is lost.
    o.adaptive = false;
    o.fixed_radius_m = 0.2;
    const auto fixed = normalFilter(scan.points, all, 2.0 * M_PI / 180, o, nullptr);
    int far_fixed = 0;
    for (int i : fixed.kept)
        if (std::hypot(scan.points(i, 0), scan.points(i, 1) - 16) < 0.4) far_fixed++;
    EXPECT_LT(far_fixed, far / 4);
}

TEST(Preprocess, IntensitiesOfAnotherLengthThrow) {
    EXPECT_THROW(intensityFilter(Eigen::VectorXd::Zero(3), 100.0, 4), std::invalid_argument);
    EXPECT_EQ(intensityFilter(Eigen::VectorXd(), 100.0, 4).size(), 4u);  // no intensity at all
}
