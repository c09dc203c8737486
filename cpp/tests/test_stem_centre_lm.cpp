#include <gtest/gtest.h>

#include "forestslam/features/dog_keypoints.hpp"
#include "forestslam/features/virtual_features.hpp"
#include "forestslam/registration/stem_centre_lm.hpp"
#include "tls_scene.hpp"

using namespace forestslam;

namespace {

double rotationErrorDeg(const Eigen::Matrix4d &a, const Eigen::Matrix4d &b) {
    const Eigen::Matrix3d d = a.block<3, 3>(0, 0).transpose() * b.block<3, 3>(0, 0);
    return Eigen::AngleAxisd(d).angle() * 180.0 / M_PI;
}

struct Frame {
    VirtualFeatures vf;
    DogKeypoints kp;
};

Frame makeFrame(const test::Scene &scene, const Pose3 &T_world_sensor) {
    std::vector<std::uint16_t> rings;
    const Points3 scan = test::raycast(scene, T_world_sensor, rings, 16, 0.2, 40.0, 0.003);
    return {extractVirtualFeaturesRings(scan, rings), detectDogKeypoints(scan)};
}

}  // namespace

TEST(StemCentreLm, RecoversKnownSixDofPerturbation) {
    const auto scene = test::defaultScene();
    const StemCentreTarget target(test::denseMap(scene, 14.0, 0.04));
    const Pose3 T_true = test::makePose(0.6, -0.4, 0.2, 0.02, -0.015, 0.3);
    const Frame f = makeFrame(scene, T_true);
    ASSERT_GE(f.vf.stems.rows(), 3);
    const Pose3 delta = test::makePose(0.2, -0.15, 0.08, 0.015, 0.01, 0.04);
    const Eigen::Matrix4d T_init = (delta * T_true).matrix();
    const auto r = registerStemCentreLm(target, f.vf.centres, f.vf.radii, f.kp.points, T_init);
    EXPECT_TRUE(r.converged);
    EXPECT_FALSE(r.degenerate);
    EXPECT_GT(r.virtual_inliers, 10);
    EXPECT_GT(r.real_inliers, 50);
    EXPECT_LT((r.T_target_source.block<3, 1>(0, 3) - T_true.translation()).norm(), 0.01);
    EXPECT_LT(rotationErrorDeg(r.T_target_source, T_true.matrix()), 0.1);
    EXPECT_LT(r.virtual_rms_m, 0.02);
    // Covariance is a proper (symmetric positive definite) 6x6 with sub-cm standard deviations.
    const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(r.covariance);
    EXPECT_GT(eig.eigenvalues().minCoeff(), 0.0);
    EXPECT_LT(std::sqrt(r.covariance(0, 0)), 0.01);
}

TEST(StemCentreLm, FrameWithoutStemsRegistersOnRealFeatures) {
    const auto scene = test::defaultScene(false);
    const StemCentreTarget target(test::denseMap(scene, 14.0, 0.04));
    const Pose3 T_true = test::makePose(-0.5, 0.8, 0.1, -0.01, 0.02, -0.6);
    const Frame f = makeFrame(scene, T_true);
    EXPECT_EQ(f.vf.centres.rows(), 0);
    const Pose3 delta = test::makePose(0.15, 0.1, -0.05, 0.01, -0.01, 0.03);
    const auto r = registerStemCentreLm(target, f.vf.centres, f.vf.radii, f.kp.points,
                                        (delta * T_true).matrix());
    EXPECT_TRUE(r.converged);
    EXPECT_EQ(r.virtual_inliers, 0);
    EXPECT_LT((r.T_target_source.block<3, 1>(0, 3) - T_true.translation()).norm(), 0.02);
    EXPECT_LT(rotationErrorDeg(r.T_target_source, T_true.matrix()), 0.2);
}

TEST(StemCentreLm, TooFewFeaturesIsDegenerateAndKeepsInitialGuess) {
    const auto scene = test::defaultScene();
    const StemCentreTarget target(test::denseMap(scene, 6.0, 0.1));
    const Eigen::Matrix4d T_init = test::makePose(1.0, 2.0, 0.0, 0.0, 0.0, 0.1).matrix();
    const auto r =
        registerStemCentreLm(target, Points3(0, 3), Eigen::VectorXd(0), Points3(0, 3), T_init);
    EXPECT_FALSE(r.converged);
    EXPECT_TRUE(r.degenerate);
    EXPECT_TRUE(r.T_target_source.isApprox(T_init));
    const StemCentreTarget empty(Points3(0, 3));
    Points3 one(1, 3);
    one << 0.0, 0.0, 0.0;
    const auto e = registerStemCentreLm(empty, one, Eigen::VectorXd::Ones(1), one, T_init);
    EXPECT_FALSE(e.converged);
    EXPECT_TRUE(e.degenerate);
}
