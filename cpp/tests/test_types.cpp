#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "forestslam/common/types.hpp"

using forestslam::Points3;

TEST(Types, FiniteRowsDropsAnyNonFiniteCoordinate) {
    Points3 p(4, 3);
    const double nan = std::numeric_limits<double>::quiet_NaN();
    p << 1, 2, 3, nan, 0, 0, 4, 5, 6, 0, INFINITY, 0;
    const Points3 f = forestslam::finiteRows(p);
    ASSERT_EQ(f.rows(), 2);
    EXPECT_DOUBLE_EQ(f(0, 0), 1.0);
    EXPECT_DOUBLE_EQ(f(1, 2), 6.0);
}

TEST(Types, TransformPointsMatchesIsometry) {
    forestslam::Pose3 T = forestslam::Pose3::Identity();
    T.rotate(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()));
    T.translation() << 1.0, -2.0, 0.5;
    Points3 p(2, 3);
    p << 1, 0, 0, 0, 2, 3;
    const Points3 q = forestslam::transformPoints(T, p);
    for (int i = 0; i < 2; ++i) {
        const Eigen::Vector3d expected = T * Eigen::Vector3d(p.row(i).transpose());
        EXPECT_NEAR((q.row(i).transpose() - expected).norm(), 0.0, 1e-12);
    }
}
