#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <random>
#include <stdexcept>
#include <thread>
#include <vector>

#include "forestslam/registration/point_to_plane_icp.hpp"
#include "registration_fixtures.hpp"

using namespace forestslam;

namespace {

Pose3 knownPose() {
    Pose3 T = Pose3::Identity();
    T.linear() = (Eigen::AngleAxisd(0.08, Eigen::Vector3d::UnitZ()) *
                  Eigen::AngleAxisd(0.02, Eigen::Vector3d::UnitX()) *
                  Eigen::AngleAxisd(-0.015, Eigen::Vector3d::UnitY()))
                     .toRotationMatrix();
    T.translation() << 0.35, -0.2, 0.05;
    return T;
}

void expectPoseNear(const Pose3 &a, const Pose3 &b, double meters, double degrees) {
    EXPECT_LT((a.translation() - b.translation()).norm(), meters);
    const double angle = Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
    EXPECT_LT(angle * 180.0 / M_PI, degrees);
}

}  // namespace

TEST(PointToPlaneIcp, JacobianMatchesNumeric) {
    const Pose3 T = knownPose();
    const Eigen::Vector3d p(2.0, -1.0, 0.7), q(2.5, -1.2, 0.6),
        n = Eigen::Vector3d(0.3, 0.5, 0.8).normalized();
    Eigen::Matrix<double, 1, 6> J;
    registration::pointToPlaneResidual(T, p, q, n, &J);
    const double h = 1e-6;
    for (int k = 0; k < 6; ++k) {
        Vector6d d = Vector6d::Zero();
        d(k) = h;
        const double rp =
            registration::pointToPlaneResidual(registration::expSE3(d) * T, p, q, n, nullptr);
        const double rm =
            registration::pointToPlaneResidual(registration::expSE3(-d) * T, p, q, n, nullptr);
        EXPECT_NEAR(J(k), (rp - rm) / (2 * h), 1e-6) << "column " << k;
    }
}

TEST(PointToPlaneIcp, ScanAgainstItselfMovedRecoversTransform) {
    const auto stems = synth::randomStems(15, 15.0, 1);
    const Points3 target = synth::sceneCloud(stems, 15.0, 2);
    const Pose3 T = knownPose();
    const Points3 source = transformPoints(T.inverse(), target);
    const registration::PlaneTarget plane_target(target, 10);
    const registration::RegistrationResult r =
        registration::icpPointToPlane(plane_target, source, Pose3::Identity());
    expectPoseNear(Pose3(r.T_target_source), T, 0.01, 0.1);
    EXPECT_TRUE(r.converged);
    EXPECT_FALSE(r.degenerate);
    EXPECT_LT(r.rmse, 0.01);
    EXPECT_GT(r.inliers, source.rows() / 2);
    EXPECT_LT(r.covariance(0, 0), 1e-4);
}

TEST(PointToPlaneIcp, NoisyResampledScanRecoversTransform) {
    const auto stems = synth::randomStems(15, 15.0, 4);
    const Points3 target = synth::sceneCloud(stems, 15.0, 5, 0.01);
    const Pose3 T = knownPose();
    const Points3 source = transformPoints(T.inverse(), synth::sceneCloud(stems, 15.0, 6, 0.01));
    const registration::RegistrationResult r =
        registration::icpPointToPlane(registration::PlaneTarget(target), source, Pose3::Identity());
    expectPoseNear(Pose3(r.T_target_source), T, 0.03, 0.2);
}

// The coarse iterations on every n-th point only bring the pose into the basin: the result and
// its covariance come from iterations on all points, as without the stride.
TEST(PointToPlaneIcp, CoarseStrideEndsOnTheFullSolutionAndItsCovariance) {
    const auto stems = synth::randomStems(15, 15.0, 4);
    const Points3 target = synth::sceneCloud(stems, 15.0, 5, 0.01);
    const Pose3 T = knownPose();
    const Points3 source = transformPoints(T.inverse(), synth::sceneCloud(stems, 15.0, 6, 0.01));
    const registration::PlaneTarget plane_target(target);
    registration::IcpConfig all, coarse;
    all.coarse_stride = 1;
    coarse.coarse_stride = 4;
    const registration::RegistrationResult a =
        registration::icpPointToPlane(plane_target, source, Pose3::Identity(), all);
    const registration::RegistrationResult c =
        registration::icpPointToPlane(plane_target, source, Pose3::Identity(), coarse);
    ASSERT_TRUE(a.converged);
    ASSERT_TRUE(c.converged);
    expectPoseNear(Pose3(c.T_target_source), Pose3(a.T_target_source), 1e-3, 0.01);
    EXPECT_NEAR(c.inliers, a.inliers, 0.01 * a.inliers);  // counted over every point
    for (int k = 0; k < 6; ++k)
        EXPECT_NEAR(c.covariance(k, k), a.covariance(k, k), 0.05 * a.covariance(k, k));
}

TEST(PointToPlaneIcp, FlatGroundOnlyIsDegenerateAndPriorHoldsIt) {
    Points3 ground(0, 3);
    std::vector<Eigen::Vector3d> pts;
    for (double x = -10; x <= 10; x += 0.5)
        for (double y = -10; y <= 10; y += 0.5) pts.emplace_back(x, y, -1.0);
    ground.resize(pts.size(), 3);
    for (size_t i = 0; i < pts.size(); ++i) ground.row(i) = pts[i].transpose();
    const Pose3 prior = Pose3(Eigen::Translation3d(0.4, 0.1, 0.0));
    Matrix6d info = Matrix6d::Identity() * 100.0;
    const registration::RegistrationResult r = registration::icpPointToPlane(
        registration::PlaneTarget(ground), ground, prior, {}, info, prior);
    EXPECT_TRUE(r.degenerate);
    // x, y, yaw unobserved by a plane: the prior keeps them.
    expectPoseNear(Pose3(r.T_target_source), prior, 1e-3, 0.01);
    EXPECT_GT(r.covariance(0, 0), 100.0 * r.covariance(2, 2));
}

TEST(PointToPlaneIcp, EmptyInputs) {
    Points3 empty(0, 3);
    const auto stems = synth::randomStems(5, 10.0, 1);
    const Points3 cloud = synth::sceneCloud(stems, 10.0, 2);
    registration::RegistrationResult r =
        registration::icpPointToPlane(registration::PlaneTarget(empty), cloud, Pose3::Identity());
    EXPECT_FALSE(r.converged);
    EXPECT_TRUE(r.degenerate);
    r = registration::icpPointToPlane(registration::PlaneTarget(cloud), empty, Pose3::Identity());
    EXPECT_FALSE(r.converged);
    EXPECT_TRUE(r.T_target_source.matrix().isIdentity());
}

TEST(PointToPlaneIcp, NonFinitePosesThrow) {
    const auto stems = synth::randomStems(5, 10.0, 1);
    const Points3 cloud = synth::sceneCloud(stems, 10.0, 2);
    const registration::PlaneTarget target(cloud);
    Pose3 nan = Pose3::Identity();
    nan.translation().z() = std::numeric_limits<double>::quiet_NaN();
    EXPECT_THROW(registration::icpPointToPlane(target, cloud, nan), std::invalid_argument);
    EXPECT_THROW(registration::icpPointToPlane(target, cloud, Pose3::Identity(), {},
                                               Matrix6d::Identity(), nan),
                 std::invalid_argument);
}

TEST(PointToPlaneIcp, NearestMatchesBruteForceAndRespectsGate) {
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-5.0, 5.0);
    Points3 pts(3000, 3);
    for (Eigen::Index i = 0; i < pts.rows(); ++i) pts.row(i) << u(rng), u(rng), 0.2 * u(rng);
    pts.row(17) = pts.row(16);  // duplicates are fine
    const registration::PlaneTarget target(pts, 10);
    for (int q = 0; q < 500; ++q) {
        const Eigen::Vector3d query(1.2 * u(rng), 1.2 * u(rng), 0.5 * u(rng));
        Eigen::Index best = 0;
        const double truth =
            (pts.rowwise() - query.transpose()).rowwise().squaredNorm().minCoeff(&best);
        double d2 = -1;
        const int j = target.nearest(query, d2);
        ASSERT_GE(j, 0);
        EXPECT_NEAR(d2, truth, 1e-12);
        EXPECT_NEAR((pts.row(j).transpose() - query).squaredNorm(), truth, 1e-12);
        double g2 = -1;
        const double gate = 0.3;
        const int jg = target.nearest(query, gate, g2);
        if (truth <= gate * gate) {
            EXPECT_NEAR(g2, truth, 1e-12);
            EXPECT_GE(jg, 0);
        } else {
            EXPECT_EQ(jg, -1);
        }
    }
    double d2 = 0;
    EXPECT_EQ(registration::PlaneTarget(Points3(0, 3)).nearest(Eigen::Vector3d::Zero(), d2), -1);
    // Points on a tilted plane get its normal.
    Points3 plane(400, 3);
    for (int i = 0; i < 400; ++i)
        plane.row(i) << (i % 20) * 0.1, (i / 20) * 0.1, 0.5 * (i % 20) * 0.1;
    const registration::PlaneTarget pt(plane, 10);
    const Eigen::Vector3d n = Eigen::Vector3d(-0.5, 0.0, 1.0).normalized();
    EXPECT_NEAR(std::abs(pt.normals().row(210).dot(n)), 1.0, 1e-9);
}

// Normals are computed on first use: any order of single-row queries, from several threads at
// once, gives bitwise the normals of the whole-target accessor, and they are the PCA normals.
TEST(PointToPlaneIcp, LazyNormalsMatchWholeTargetFromAnyOrderAndThreads) {
    std::mt19937 rng(7);
    std::normal_distribution<double> noise(0.0, 0.005);
    std::uniform_real_distribution<double> u(-3.0, 3.0);
    Points3 pts(1500, 3);
    for (int i = 0; i < 1000; ++i) pts.row(i) << u(rng), u(rng), noise(rng);  // ground
    for (int i = 1000; i < 1400; ++i) {  // a stem of radius 0.2 m: 20 rings of 20 points
        const double a = 2.0 * M_PI * (i % 20) / 20.0;
        pts.row(i) << 1.0 + 0.2 * std::cos(a), 0.5 + 0.2 * std::sin(a),
            0.5 + 0.1 * ((i - 1000) / 20);
    }
    for (int i = 1400; i < 1500; ++i) pts.row(i) << -10.0 + 0.05 * (i - 1400), -10.0, 2.0;  // line
    const registration::PlaneTarget whole(pts, 10);
    const Points3 all = whole.normals();
    const registration::PlaneTarget lazy(pts, 10);
    std::vector<int> order(1500);
    std::iota(order.begin(), order.end(), 0);
    std::shuffle(order.begin(), order.end(), rng);
    // Two threads per half of the rows: each row is asked for by two threads at about once.
    std::vector<std::vector<Eigen::Vector3d>> got(
        4, std::vector<Eigen::Vector3d>(1500, Eigen::Vector3d::Zero()));
    std::vector<std::thread> threads;
    for (int t = 0; t < 4; ++t)
        threads.emplace_back([&, t] {
            for (int k = t % 2; k < 1500; k += 2) got[t][order[k]] = lazy.normal(order[k]);
        });
    for (auto &th : threads) th.join();
    for (int i = 0; i < 1500; ++i) {
        const Eigen::Vector3d want = all.row(i).transpose();
        for (const auto &g : got) {
            const Eigen::Vector3d &n = g[static_cast<size_t>(i)];
            if (n.isZero()) continue;  // a row this thread did not ask for
            if (std::isnan(want.x()))
                EXPECT_TRUE(std::isnan(n.x())) << i;
            else
                EXPECT_EQ(n, want) << i;  // bitwise: the same computation
        }
        const Eigen::Vector3d again = lazy.normal(i);
        EXPECT_TRUE(std::isnan(want.x()) ? std::isnan(again.x()) : again == want) << i;
    }
    for (int i = 0; i < 1000; i += 50) EXPECT_GT(std::abs(all(i, 2)), 0.99) << i;     // ground: z
    for (int i = 1000; i < 1400; i += 50) EXPECT_LT(std::abs(all(i, 2)), 0.05) << i;  // stem
    for (int i = 1410; i < 1490; ++i) EXPECT_TRUE(std::isnan(all(i, 0))) << i;  // a line: none
    EXPECT_THROW(lazy.normal(-1), std::out_of_range);
    EXPECT_THROW(lazy.normal(1500), std::out_of_range);
}
