#include <gtest/gtest.h>

#include <limits>
#include <stdexcept>

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
    const Pose3 T_ab_true = T_a.inverse() * T_b;
    const registration::NdtResult r = registration::registerNdt(a, b);
    ASSERT_TRUE(r.converged);
    EXPECT_LT((r.T_target_source.translation() - T_ab_true.translation()).norm(), 0.1);
}

TEST(Ndt, TooFewPointsKeepsInitialGuess) {
    Points3 few(3, 3);
    few.setRandom();
    const Pose3 T0 = test::makePose(1.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    const registration::NdtResult r = registration::registerNdt(few, few, T0);
    EXPECT_FALSE(r.converged);
    EXPECT_TRUE(r.T_target_source.isApprox(T0));
}

TEST(Ndt, NonFiniteInitialGuessThrows) {
    Points3 few(3, 3);
    few.setRandom();
    Pose3 T0 = Pose3::Identity();
    T0.translation().x() = std::numeric_limits<double>::quiet_NaN();
    EXPECT_THROW(registration::registerNdt(few, few, T0), std::invalid_argument);
}
