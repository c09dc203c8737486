#include <gtest/gtest.h>

#include <random>
#include <stdexcept>

#include "forestslam/registration/deskew.hpp"

using namespace forestslam;

TEST(Deskew, MatchesTheConstantVelocityPoseOfEachPoint) {
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> u(-20.0, 20.0), ut(-0.05, 0.05);
    Points3 p(200, 3);
    Eigen::VectorXd t(200);
    for (int i = 0; i < 200; ++i) p.row(i) << u(rng), u(rng), 0.1 * u(rng), t(i) = ut(rng);
    Vector6d twist;
    twist << 1.2, -0.3, 0.05, 0.02, -0.04, 0.8;
    const Points3 out = registration::deskewPoints(p, t, twist);
    for (int i = 0; i < 200; ++i) {
        const Eigen::Vector3d rv = t(i) * twist.tail<3>();
        const Eigen::Matrix3d R =
            rv.norm() > 0 ? Eigen::AngleAxisd(rv.norm(), rv.normalized()).toRotationMatrix()
                          : Eigen::Matrix3d::Identity();
        const Eigen::Vector3d expect = R * p.row(i).transpose() + t(i) * twist.head<3>();
        EXPECT_NEAR((out.row(i).transpose() - expect).norm(), 0.0, 1e-12);
    }
}

TEST(Deskew, ZeroMotionNonFiniteTimesAndWrongSizes) {
    Points3 p(3, 3);
    p << 1, 2, 3, 4, 5, 6, 7, 8, 9;
    Eigen::VectorXd t(3);
    t << 0.01, std::nan(""), -0.02;
    Vector6d still = Vector6d::Zero();
    EXPECT_TRUE(registration::deskewPoints(p, t, still).isApprox(p));
    Vector6d moving = Vector6d::Zero();
    moving(0) = 1.0;
    const Points3 out = registration::deskewPoints(p, t, moving);
    EXPECT_NEAR(out(0, 0), 1.01, 1e-12);
    EXPECT_EQ(out.row(1), p.row(1));  // NaN time: unchanged
    EXPECT_NEAR(out(2, 0), 6.98, 1e-12);
    EXPECT_THROW(registration::deskewPoints(p, Eigen::VectorXd(2), moving), std::invalid_argument);
    EXPECT_EQ(registration::deskewPoints(Points3(0, 3), Eigen::VectorXd(0), moving).rows(), 0);
}
