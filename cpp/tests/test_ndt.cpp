#include <gtest/gtest.h>

#include "forestslam/registration/ndt.hpp"
#include "tls_scene.hpp"

using namespace forestslam;

TEST(Ndt, ConsecutiveFramesRelativeMotion) {
    const auto scene = test::defaultScene();
    std::vector<std::uint16_t> rings;
    const Pose3 T_a = test::makePose(0.0, 0.0, 0.0, 0.0, 0.0, 0.1);
    const Pose3 T_b = test::makePose(0.5, 0.2, 0.0, 0.01, 0.0, 0.15);
    const Points3 a = test::raycast(scene, T_a, rings);
    const Points3 b = test::raycast(scene, T_b, rings);
    const Eigen::Matrix4d T_ab_true = (T_a.inverse() * T_b).matrix();
    const NdtResult r = registerNdt(a, b);
    ASSERT_TRUE(r.converged);
    EXPECT_LT((r.T_target_source.block<3, 1>(0, 3) - T_ab_true.block<3, 1>(0, 3)).norm(), 0.1);
}

TEST(Ndt, TooFewPointsKeepsInitialGuess) {
    Points3 few(3, 3);
    few.setRandom();
    const Eigen::Matrix4d T0 = test::makePose(1.0, 0.0, 0.0, 0.0, 0.0, 0.0).matrix();
    const NdtResult r = registerNdt(few, few, T0);
    EXPECT_FALSE(r.converged);
    EXPECT_TRUE(r.T_target_source.isApprox(T0));
}
