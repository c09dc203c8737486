#include <gtest/gtest.h>

#include "forestslam/common/pcl_adapter.hpp"

TEST(PclAdapter, RoundTripKeepsFloatPrecision) {
    forestslam::Points3 p(3, 3);
    p << 1.25, -2.5, 3.0, 100.125, 0.0, -7.75, 0.1, 0.2, 0.3;
    const auto cloud = forestslam::detail::toPcl(p);
    ASSERT_EQ(cloud->size(), 3u);
    const forestslam::Points3 back = forestslam::detail::fromPcl(*cloud);
    EXPECT_NEAR((back - p).cwiseAbs().maxCoeff(), 0.0, 1e-5);
}
