#include <gtest/gtest.h>

#include <stdexcept>

#include "forestslam/odometry/motion_model.hpp"

using namespace forestslam;
using namespace forestslam::odometry;

namespace {

Pose3 planar(double x, double y, double yaw) {
    Pose3 T = Pose3::Identity();
    T.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T.translation() << x, y, 0;
    return T;
}

}  // namespace

TEST(MotionModel, TwistRoundTrip) {
    Vector6d xi;
    xi << 0.3, -0.1, 0.05, 0.02, -0.01, 0.2;
    EXPECT_TRUE(poseToTwist(twistToPose(xi)).isApprox(xi, 1e-12));
}

TEST(MotionModel, PredictsAtConstantVelocity) {
    ConstantVelocityModel m;
    EXPECT_TRUE(m.predict(0.0).isApprox(Pose3::Identity()));
    m.update(0.0, Pose3::Identity());
    m.update(0.1, planar(0.1, 0, 0.01));  // 1 m/s, 0.1 rad/s
    EXPECT_FALSE(m.beginScan(0.2).restarted);
    const Pose3 T = m.predict(0.2);
    EXPECT_NEAR(T.translation().x(), 0.1 + 0.1 * std::cos(0.01), 1e-9);
    EXPECT_NEAR(std::atan2(T(1, 0), T(0, 0)), 0.02, 1e-12);
}

TEST(MotionModel, ClampsTheVelocity) {
    MotionModelConfig c;
    c.max_speed_mps = 2.0;
    ConstantVelocityModel m(c);
    m.update(0.0, Pose3::Identity());
    m.update(0.1, planar(1.0, 0, 0));  // 10 m/s: a wrong registration
    EXPECT_NEAR(m.twist().head<3>().norm(), 2.0, 1e-12);
}

// Issue 19, 3: a 120 s gap must not multiply the prediction by the gap.
TEST(MotionModel, LongGapRestartsWithoutJump) {
    ConstantVelocityModel m;
    for (int k = 0; k < 10; ++k) m.update(0.1 * k, planar(0.1 * k, 0, 0));  // 1 m/s
    const StampCheck check = m.beginScan(0.9 + 120.0);
    EXPECT_TRUE(check.restarted);
    EXPECT_NEAR(check.gap_s, 120.0, 1e-9);
    EXPECT_TRUE(m.twist().isZero());
    EXPECT_NEAR(m.predict(120.9).translation().x(), 0.9, 1e-12);  // the last pose, not +120 m
    // The velocity is not estimated across the gap, but again from the next normal step.
    m.update(120.9, planar(1.0, 0, 0));
    EXPECT_TRUE(m.twist().isZero());
    EXPECT_FALSE(m.beginScan(121.0).restarted);
    m.update(121.0, planar(1.1, 0, 0));
    EXPECT_NEAR(m.twist()(0), 1.0, 1e-9);
}

TEST(MotionModel, JumpBackRestarts) {
    ConstantVelocityModel m;
    m.update(10.0, Pose3::Identity());
    m.update(10.1, planar(0.1, 0, 0));
    const StampCheck back = m.beginScan(5.0);
    EXPECT_TRUE(back.restarted);
    EXPECT_LT(back.gap_s, 0.0);
    EXPECT_NEAR(m.predict(5.0).translation().x(), 0.1, 1e-12);
    EXPECT_TRUE(m.beginScan(10.1).restarted);  // the same time again
}

TEST(MotionModel, UntrustedPosesAreNotKept) {
    ConstantVelocityModel m;
    m.update(0.0, Pose3::Identity());
    m.update(0.1, planar(0.1, 0, 0));                           // 1 m/s
    m.update(0.2, planar(5.0, 0, 0), false);                    // a doubtful registration
    EXPECT_NEAR(m.predict(0.3).translation().x(), 0.3, 1e-12);  // from the trusted one
    m.update(0.3, planar(0.3, 0, 0));
    EXPECT_NEAR(m.twist()(0), 1.0, 1e-12);  // kept, not estimated across the doubtful pose
    m.update(0.4, planar(0.35, 0, 0));
    EXPECT_NEAR(m.twist()(0), 0.5, 1e-9);
}

// A trusted pose after a doubtful one keeps the velocity without measuring it again: the
// velocity still expires max_gap_s after it was measured (the MLS-to-TLS walk's rule).
TEST(MotionModel, AVelocityExpiresAfterMaxGapSinceItWasMeasured) {
    MotionModelConfig c;
    c.max_gap_s = 0.5;
    ConstantVelocityModel m(c);
    m.update(0.0, Pose3::Identity());
    m.update(0.1, planar(0.1, 0, 0));  // 1 m/s, measured at 0.1
    for (int k = 2; k <= 5; ++k) {     // doubtful, trusted, doubtful, trusted: not re-measured
        EXPECT_FALSE(m.beginScan(0.1 * k).restarted);
        m.update(0.1 * k, planar(0.1 * k, 0, 0), k % 2 == 1);
    }
    EXPECT_NEAR(m.twist()(0), 1.0, 1e-12);  // 0.4 s old: kept
    EXPECT_FALSE(m.beginScan(0.7).restarted);
    EXPECT_TRUE(m.twist().isZero());  // 0.6 s old: expired, while the pose is 0.2 s old
    m.update(0.7, planar(0.8, 0, 0));
    EXPECT_NEAR(m.twist()(0), 1.5, 1e-9);  // measured again from consecutive trusted poses
}

TEST(MotionModel, DeskewNeedsOneTimePerPoint) {
    ConstantVelocityModel m;
    m.update(0.0, Pose3::Identity());
    m.update(0.1, planar(0.1, 0, 0));
    const Points3 p = Points3::Random(4, 3);
    EXPECT_THROW(m.deskew(p, Eigen::VectorXd::Zero(3)), std::invalid_argument);
    const Points3 out = m.deskew(p, Eigen::VectorXd::Constant(4, 0.05));
    EXPECT_NEAR(out(0, 0) - p(0, 0), 0.05, 1e-12);
}

TEST(MotionModel, RejectsNonsenseConfig) {
    MotionModelConfig c;
    c.max_gap_s = 0.0;
    EXPECT_THROW(ConstantVelocityModel{c}, std::invalid_argument);
}
