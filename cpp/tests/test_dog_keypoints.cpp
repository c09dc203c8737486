#include <gtest/gtest.h>

#include <random>

#include "forestslam/features/dog_keypoints.hpp"
#include "tls_scene.hpp"

using namespace forestslam;

namespace {

// Share of keypoints a that have a keypoint of b within tol.
double matchedShare(const Points3 &a, const Points3 &b, double tol) {
    int matched = 0;
    for (Eigen::Index i = 0; i < a.rows(); ++i) {
        for (Eigen::Index j = 0; j < b.rows(); ++j) {
            if ((a.row(i) - b.row(j)).norm() < tol) {
                ++matched;
                break;
            }
        }
    }
    return a.rows() ? static_cast<double>(matched) / a.rows() : 0.0;
}

}  // namespace

TEST(DogKeypoints, CountBoundedAndSpread) {
    const auto scene = test::defaultScene();
    std::vector<std::uint16_t> rings;
    const Points3 scan = test::raycast(scene, Pose3::Identity(), rings);
    features::DogKeypointsConfig cfg;
    const features::DogKeypoints kp = features::detectDogKeypoints(scan, cfg);
    EXPECT_GE(kp.points.rows(), 50);
    EXPECT_LE(kp.points.rows(), cfg.max_keypoints);
    ASSERT_EQ(kp.response.size(), kp.points.rows());
    // Non-maximum suppression: no two keypoints closer than the NMS radius.
    for (Eigen::Index i = 0; i < kp.points.rows(); ++i) {
        for (Eigen::Index j = i + 1; j < kp.points.rows(); ++j) {
            EXPECT_GE((kp.points.row(i) - kp.points.row(j)).norm(), cfg.nms_radius_m);
        }
    }
}

TEST(DogKeypoints, StableUnderRigidTransform) {
    // Response and non-maximum suppression are rigid-motion invariant; the voxel buckets that
    // cap the count are axis-aligned, so the cap is lifted and voxelisation skipped here.
    const auto scene = test::defaultScene();
    Points3 map = test::denseMap(scene, 5.0, 0.08);
    std::mt19937 rng(3);
    std::normal_distribution<double> noise(0.0, 0.005);
    for (Eigen::Index i = 0; i < map.rows(); ++i) {
        for (int k = 0; k < 3; ++k) map(i, k) += noise(rng);
    }
    const Pose3 T = test::makePose(3.7, -2.2, 0.4, 0.05, -0.04, 0.9);
    features::DogKeypointsConfig cfg;
    cfg.voxel_m = 0.0;
    cfg.sigma_small_m = 0.1;
    cfg.sigma_large_m = 0.2;
    cfg.nms_radius_m = 0.4;
    cfg.max_keypoints = 100000;
    const features::DogKeypoints a = features::detectDogKeypoints(map, cfg);
    const features::DogKeypoints b = features::detectDogKeypoints(transformPoints(T, map), cfg);
    ASSERT_GE(a.points.rows(), 30);
    EXPECT_GE(matchedShare(transformPoints(T, a.points), b.points, 0.02), 0.9);
    EXPECT_GE(matchedShare(b.points, transformPoints(T, a.points), 0.02), 0.9);
}

TEST(DogKeypoints, DegenerateInputs) {
    EXPECT_EQ(features::detectDogKeypoints(Points3(0, 3)).points.rows(), 0);
    Points3 one(1, 3);
    one << 1.0, 2.0, 3.0;
    EXPECT_EQ(features::detectDogKeypoints(one).points.rows(), 0);
    Points3 nan = Points3::Constant(100, 3, std::numeric_limits<double>::quiet_NaN());
    EXPECT_EQ(features::detectDogKeypoints(nan).points.rows(), 0);
}
