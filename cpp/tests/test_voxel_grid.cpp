#include <gtest/gtest.h>

#include <limits>

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
