#include <gtest/gtest.h>

#include <random>
#include <stdexcept>

#include "forestslam/odometry/tree_odometry.hpp"
#include "perception_scene.hpp"

using namespace forestslam;
using namespace forestslam::odometry;

namespace {

// A random stand (seeded) and a VLP-16 scan of it from a planar pose (x, y, yaw).
std::vector<test::Tree> stand(unsigned seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> xy(-30.0, 40.0), dbh(0.2, 0.5);
    std::vector<test::Tree> trees;
    while (trees.size() < 60) {
        const test::Tree t{xy(rng), xy(rng), dbh(rng)};
        bool free = std::hypot(t.x, t.y) > 3.0;
        for (const auto &o : trees) free = free && std::hypot(t.x - o.x, t.y - o.y) > 2.5;
        if (free) trees.push_back(t);
    }
    return trees;
}

LidarScan scanFrom(const std::vector<test::Tree> &world, double x, double y, double yaw,
                   double stamp, unsigned seed) {
    std::vector<test::Tree> local;
    const double c = std::cos(yaw), s = std::sin(yaw);
    for (const auto &t : world)
        local.push_back({c * (t.x - x) + s * (t.y - y), -s * (t.x - x) + c * (t.y - y), t.dbh});
    const test::SceneScan cast = test::castScan(local, 1.8, 0.01, seed);
    LidarScan scan;
    scan.stamp = stamp;
    scan.points = cast.points;
    scan.ring = cast.ring;
    return scan;
}

OdometrySensor vlp16() {
    OdometrySensor s;
    s.geometry = test::vlp16Geometry();
    return s;
}

}  // namespace

TEST(TreeOdometry, FollowsADrivenArc) {
    const auto world = stand(7);
    TreeOdometry odo(vlp16());
    OdometryResult last;
    for (int k = 0; k < 15; ++k) {
        const double t = 0.1 * k;  // 1 m/s along x, turning 0.1 rad/s
        last = odo.registerScan(scanFrom(world, t, 0.02 * k * k * 0.01, 0.1 * t, t, k));
        if (k == 0) EXPECT_EQ(last.method, "first");
    }
    EXPECT_EQ(last.method, "trees");
    EXPECT_FALSE(last.degraded);
    EXPECT_GE(last.matched_stems, 5);
    const double t = 1.4;
    EXPECT_NEAR(last.T_world_sensor(0, 3), t, 0.05);
    EXPECT_NEAR(last.T_world_sensor(1, 3), 0.02 * 14 * 14 * 0.01, 0.05);
    EXPECT_NEAR(std::atan2(last.T_world_sensor(1, 0), last.T_world_sensor(0, 0)), 0.1 * t, 0.005);
    EXPECT_TRUE(last.has_covariance6);
    EXPECT_GT(last.detection.stems.size(), 5u);
    EXPECT_GT(last.cpu_ms.at("perception"), 0.0);
}

// Issue 19, 3: 120 s without scans (a paused recording) while the machine stood still. The old
// model multiplied the prediction by the gap (120 m) and kept it; now it restarts.
TEST(TreeOdometry, LongStampGapDoesNotJump) {
    const auto world = stand(11);
    TreeOdometry odo(vlp16());
    for (int k = 0; k < 10; ++k) odo.registerScan(scanFrom(world, 0.1 * k, 0, 0, 0.1 * k, k));
    const OdometryResult r = odo.registerScan(scanFrom(world, 1.0, 0, 0, 120.9, 99));
    EXPECT_TRUE(r.stamp_check.restarted);
    EXPECT_NEAR(r.stamp_check.gap_s, 120.0, 1e-6);
    EXPECT_NEAR(r.T_world_sensor(0, 3), 1.0, 0.05);
    EXPECT_NEAR(r.T_world_sensor(1, 3), 0.0, 0.05);
    const OdometryResult next = odo.registerScan(scanFrom(world, 1.1, 0, 0, 121.0, 100));
    EXPECT_FALSE(next.stamp_check.restarted);
    EXPECT_NEAR(next.T_world_sensor(0, 3), 1.1, 0.05);
}

TEST(TreeOdometry, EmptyScansKeepThePrediction) {
    const auto world = stand(3);
    TreeOdometry odo(vlp16());
    odo.registerScan(scanFrom(world, 0, 0, 0, 0.0, 1));
    LidarScan empty;
    empty.stamp = 0.1;
    const OdometryResult r = odo.registerScan(empty);
    EXPECT_EQ(r.method, "prediction");
    EXPECT_TRUE(r.degraded);
    EXPECT_TRUE(r.T_world_sensor.matrix().allFinite());
}

TEST(TreeOdometry, RejectsInvalidInput) {
    OdometryConfig c;
    c.method = "magic";
    EXPECT_THROW(TreeOdometry(vlp16(), c), std::invalid_argument);
    c = OdometryConfig{};
    c.registration.trees.gate_m = 0.0;  // would match no stem, silently
    EXPECT_THROW(TreeOdometry(vlp16(), c), std::invalid_argument);
    c = OdometryConfig{};
    c.registration.trees.ratio = 2.0;
    EXPECT_THROW(TreeOdometry(vlp16(), c), std::invalid_argument);
    TreeOdometry odo(vlp16());
    LidarScan scan;
    scan.points = Points3::Zero(5, 3);
    scan.time = Eigen::VectorXd::Zero(4);
    EXPECT_THROW(odo.registerScan(scan), std::invalid_argument);
}
