#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>

#include "forestslam/registration/result.hpp"
#include "forestslam/registration/tree_correspondences.hpp"

using forestslam::Points3;
using forestslam::Pose3;

TEST(TreeCorrespondences, MutualNearestUnderPrediction) {
    Points3 target(4, 3);
    target << 0, 0, 1, 3, 0, 1, 0, 3, 1, 10, 10, 1;
    const Pose3 T = forestslam::registration::planarToPose(1.0, -0.5, 0.2);
    // source = T^-1 target, shuffled, plus a stem with no partner
    Points3 source(4, 3);
    const Points3 moved = forestslam::transformPoints(T.inverse(), target);
    source.row(0) = moved.row(2);
    source.row(1) = moved.row(0);
    source.row(2) = moved.row(1);
    source << source.topRows(3), Eigen::RowVector3d(-20, -20, 1);
    const auto pairs = forestslam::registration::matchTrees(source, target, T, 0.5);
    ASSERT_EQ(pairs.size(), 3u);
    EXPECT_EQ(pairs[0], std::make_pair(0, 2));
    EXPECT_EQ(pairs[1], std::make_pair(1, 0));
    EXPECT_EQ(pairs[2], std::make_pair(2, 1));
}

TEST(TreeCorrespondences, GateAndMutualExclusion) {
    Points3 target(2, 3);
    target << 0, 0, 0, 0.3, 0, 0;
    Points3 source(1, 3);
    source << 0.2, 0, 0;
    // Only one source: it takes the nearer target; the other target stays unmatched.
    auto pairs = forestslam::registration::matchTrees(source, target, Pose3::Identity(), 1.0);
    ASSERT_EQ(pairs.size(), 1u);
    EXPECT_EQ(pairs[0].second, 1);
    // Two sources competing for one target: only the mutual nearest keeps it.
    Points3 two(2, 3);
    two << 0.1, 0, 0, 0.15, 0, 0;
    Points3 one(1, 3);
    one << 0, 0, 0;
    pairs = forestslam::registration::matchTrees(two, one, Pose3::Identity(), 1.0);
    ASSERT_EQ(pairs.size(), 1u);
    EXPECT_EQ(pairs[0].first, 0);
    // Gate
    EXPECT_TRUE(forestslam::registration::matchTrees(
                    source, target, forestslam::registration::planarToPose(5, 0, 0), 1.0)
                    .empty());
    // Ratio test drops the ambiguous pair (0.1 vs 0.1 away).
    EXPECT_TRUE(forestslam::registration::matchTrees(
                    source, target, forestslam::registration::planarToPose(-0.05, 0, 0), 1.0, 0.8)
                    .empty());
}

TEST(TreeCorrespondences, EmptyAndNonFinite) {
    Points3 empty(0, 3), one(1, 3), nan(1, 3);
    one << 0, 0, 0;
    nan << std::numeric_limits<double>::quiet_NaN(), 0, 0;
    EXPECT_TRUE(forestslam::registration::matchTrees(empty, one, Pose3::Identity(), 1.0).empty());
    EXPECT_TRUE(forestslam::registration::matchTrees(one, empty, Pose3::Identity(), 1.0).empty());
    EXPECT_TRUE(forestslam::registration::matchTrees(nan, one, Pose3::Identity(), 1.0).empty());
}

TEST(TreeCorrespondences, InvalidGateOrRatioThrows) {
    Points3 one(1, 3);
    one << 0, 0, 0;
    const Pose3 I = Pose3::Identity();
    const double nan = std::numeric_limits<double>::quiet_NaN();
    // A gate or ratio that would silently match nothing (or everything) is an error.
    EXPECT_THROW(forestslam::registration::matchTrees(one, one, I, 0.0), std::invalid_argument);
    EXPECT_THROW(forestslam::registration::matchTrees(one, one, I, nan), std::invalid_argument);
    EXPECT_THROW(forestslam::registration::matchTrees(one, one, I, 1.0, 0.0),
                 std::invalid_argument);
    EXPECT_THROW(forestslam::registration::matchTrees(one, one, I, 1.0, 1.5),
                 std::invalid_argument);
    EXPECT_THROW(forestslam::registration::matchTrees(one, one, I, 1.0, nan),
                 std::invalid_argument);
    EXPECT_EQ(forestslam::registration::matchTrees(one, one, I, 1.0, 1.0).size(), 1u);
}
