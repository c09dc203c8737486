#include <gtest/gtest.h>

#include "forestslam/odometry/local_map.hpp"

using namespace forestslam;
using namespace forestslam::odometry;

namespace {

MapFrame frameAt(double x, const Eigen::Vector3d &stem) {
    MapFrame f;
    f.T_world_sensor.translation() << x, 0, 0;
    f.stem_positions = stem.transpose();
    f.stem_covariances = registration::Covariances::Zero(1, 9);
    f.cloud = Points3::Random(200, 3) * 5.0;
    return f;
}

}  // namespace

TEST(LocalMap, KeyframesByDistanceAndMergedStems) {
    OdometryConfig c;
    c.keyframe_distance_m = 1.0;
    c.local_map_keyframes = 2;
    LocalMap map(c);
    map.add(frameAt(0.0, {5, 0, 1.3}));
    map.add(frameAt(0.5, {9, 9, 1.3}));  // too close: not a keyframe
    EXPECT_EQ(map.keyframes(), 1u);
    EXPECT_EQ(map.stemPositions().rows(), 1);
    map.add(frameAt(1.0, {5.2, 0, 1.3}));  // the same tree, seen again: the newest is kept
    EXPECT_EQ(map.keyframes(), 2u);
    ASSERT_EQ(map.stemPositions().rows(), 1);
    EXPECT_DOUBLE_EQ(map.stemPositions()(0, 0), 5.2);
    map.add(frameAt(2.0, {20, 0, 1.3}));  // the first keyframe drops out
    EXPECT_EQ(map.keyframes(), 2u);
    EXPECT_EQ(map.stemPositions().rows(), 2);
    ASSERT_NE(map.planeTarget(), nullptr);
    EXPECT_GT(map.cloud().rows(), 0);
}

TEST(LocalMap, ThinEvenlyKeepsEnds) {
    Points3 p(10, 3);
    for (int i = 0; i < 10; ++i) p.row(i) << i, 0, 0;
    const Points3 t = thinEvenly(p, 4);
    ASSERT_EQ(t.rows(), 4);
    EXPECT_EQ(t(0, 0), 0);
    EXPECT_EQ(t(1, 0), 3);
    EXPECT_EQ(t(3, 0), 9);
}
