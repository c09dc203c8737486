#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <stdexcept>
#include <vector>

#include "forestslam/features/voxel_grid.hpp"

using forestslam::Points3;
using forestslam::features::voxelDownsample;

TEST(VoxelGrid, CentroidPerVoxelAndNaNDropped) {
    Points3 p(5, 3);
    p << 0.01, 0.01, 0.01,                                   //
        0.03, 0.03, 0.03,                                    //
        0.51, 0.0, 0.0,                                      //
        std::numeric_limits<double>::quiet_NaN(), 0.0, 0.0,  //
        -0.01, 0.0, 0.0;
    std::vector<int> rep;
    const Points3 out = voxelDownsample(p, 0.1, rep);
    ASSERT_EQ(out.rows(), 3);
    ASSERT_EQ(rep.size(), 3u);
    EXPECT_NEAR(out(0, 0), 0.02, 1e-12);
    EXPECT_EQ(rep[0], 0);
    EXPECT_EQ(rep[1], 2);
    EXPECT_EQ(rep[2], 4);  // negative side is its own voxel
}

TEST(VoxelGrid, EmptyAndFarApartPoints) {
    EXPECT_EQ(voxelDownsample(Points3(0, 3), 0.1).rows(), 0);
    Points3 p(2, 3);
    p << -9000.0, 0.0, 0.0, 9000.0, 0.0, 0.0;
    EXPECT_EQ(voxelDownsample(p, 0.01).rows(), 2);
    EXPECT_EQ(voxelDownsample(p, 0.0).rows(), 2);
}

// The grouping a sort of packed voxel keys gives: voxels in (x, y, z) order of their cells,
// every point in its voxel, the inverse consistent with the order.
TEST(VoxelGrid, GroupByVoxelInCellOrder) {
    using forestslam::features::groupByVoxel;
    Points3 p(6, 3);
    p << 0.25, 0.05, 0.05,  // cell (2, 0, 0)
        0.05, 0.15, 0.05,   // (0, 1, 0)
        0.05, 0.05, 0.35,   // (0, 0, 3)
        0.21, 0.01, 0.09,   // (2, 0, 0) again
        0.05, 0.05, 0.05,   // (0, 0, 0)
        -0.05, 0.05, 0.05;  // (-1, 0, 0): below the origin is fine
    const auto g = groupByVoxel(p, Eigen::Vector3d::Zero(), 0.1);
    ASSERT_EQ(g.start.size(), 5);
    const std::vector<std::int64_t> order(g.order.data(), g.order.data() + g.order.size());
    EXPECT_EQ(order, (std::vector<std::int64_t>{5, 4, 2, 1, 0, 3}));  // stable within a voxel
    const std::vector<std::int64_t> start(g.start.data(), g.start.data() + g.start.size());
    EXPECT_EQ(start, (std::vector<std::int64_t>{0, 1, 2, 3, 4}));
    for (Eigen::Index j = 0; j < 6; ++j) {
        const auto voxel = std::upper_bound(start.begin(), start.end(), j) - start.begin() - 1;
        EXPECT_EQ(g.inverse(g.order(j)), voxel);
    }
}

TEST(VoxelGrid, GroupByVoxelRefusesWhatKeysCannotHold) {
    using forestslam::features::groupByVoxel;
    Points3 p(2, 3);
    p << 0.0, 0.0, 0.0, 3e5, 0.0, 0.0;  // 3e6 voxels of 0.1 m along x: beyond 2^21
    EXPECT_THROW(groupByVoxel(p, Eigen::Vector3d::Zero(), 0.1), std::invalid_argument);
    EXPECT_NO_THROW(groupByVoxel(p, Eigen::Vector3d::Zero(), 1.0));
    p(1, 2) = std::numeric_limits<double>::quiet_NaN();
    EXPECT_THROW(groupByVoxel(p, Eigen::Vector3d::Zero(), 1.0), std::invalid_argument);
    EXPECT_THROW(groupByVoxel(p, Eigen::Vector3d::Zero(), 0.0), std::invalid_argument);
    EXPECT_EQ(groupByVoxel(Points3(0, 3), Eigen::Vector3d::Zero(), 0.1).start.size(), 0);
}
