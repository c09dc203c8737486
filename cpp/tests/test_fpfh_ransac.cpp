#include <gtest/gtest.h>

#include <limits>
#include <stdexcept>

#include "forestslam/registration/fpfh_ransac.hpp"
#include "registration_fixtures.hpp"

using namespace forestslam;

TEST(FpfhRansac, RecoversLargeTransformWithoutInitialGuess) {
    const auto stems = synth::randomStems(20, 15.0, 7);
    const Points3 target = synth::sceneCloud(stems, 15.0, 8);
    Pose3 T = Pose3::Identity();
    T.linear() = Eigen::AngleAxisd(0.5, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T.translation() << 1.5, -1.0, 0.1;
    const Points3 source = transformPoints(T.inverse(), target);
    const registration::RegistrationResult r = registration::registerFpfh(source, target);
    const Pose3 est(r.T_target_source);
    EXPECT_LT((est.translation() - T.translation()).norm(), 0.05);
    EXPECT_LT(Eigen::AngleAxisd(est.linear().transpose() * T.linear()).angle() * 180 / M_PI, 0.5);
    EXPECT_GT(r.inliers, 10);
    EXPECT_FALSE(r.degenerate);
}

TEST(FpfhRansac, VoxelDownsampleAndEmpty) {
    Points3 p(3, 3);
    p << 0.01, 0.01, 0.01, 0.02, 0.02, 0.02, 5, 5, 5;
    EXPECT_EQ(registration::voxelCentroids(p, 0.25).rows(), 2);
    const registration::RegistrationResult r = registration::registerFpfh(Points3(0, 3), p);
    EXPECT_FALSE(r.converged);
    EXPECT_TRUE(r.degenerate);
    Pose3 nan = Pose3::Identity();
    nan.linear()(0, 0) = std::numeric_limits<double>::quiet_NaN();
    EXPECT_THROW(registration::registerFpfh(p, p, nan), std::invalid_argument);
}
