#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>

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

TEST(Types, SelectRowsKeepsOrderAndRejectsRowsOutside) {
    Points3 p(3, 3);
    p << 0, 0, 0, 1, 1, 1, 2, 2, 2;
    const Points3 s = forestslam::selectRows(p, {2, 0});
    ASSERT_EQ(s.rows(), 2);
    EXPECT_DOUBLE_EQ(s(0, 0), 2.0);
    EXPECT_DOUBLE_EQ(s(1, 0), 0.0);
    EXPECT_THROW(forestslam::selectRows(p, {0, 3}), std::out_of_range);
    EXPECT_THROW(forestslam::selectRows(p, {-1}), std::out_of_range);
}

TEST(Types, RequirePerPointNamesTheField) {
    EXPECT_NO_THROW(forestslam::requirePerPoint("f", "times", 4, 4));
    EXPECT_NO_THROW(forestslam::requirePerPoint("f", "times", 0, 4, true));
    EXPECT_THROW(forestslam::requirePerPoint("f", "times", 0, 4), std::invalid_argument);
    try {
        forestslam::requirePerPoint("deskew", "times", 3, 4);
        FAIL();
    } catch (const std::invalid_argument &e) {
        EXPECT_STREQ(e.what(), "deskew: 3 times for 4 points");
    }
}
