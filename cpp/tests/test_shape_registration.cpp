#include <ceres/numeric_diff_first_order_function.h>
#include <gtest/gtest.h>

#include <random>
#include <stdexcept>

#include "forestslam/registration/shape_registration.hpp"
#include "forestslam/registration/tree_correspondences.hpp"
#include "registration_fixtures.hpp"

using namespace forestslam;

namespace {

struct Scene {
    Points3 src_means, tgt_means;
    registration::Covariances src_covs, tgt_covs;
};

// Target stems in the target frame; source = the same stems seen from T_target_source (noisy).
Scene makeScene(int n, const Pose3 &T, double noise, unsigned seed) {
    std::mt19937 rng(seed);
    std::normal_distribution<double> g(0.0, noise > 0 ? noise : 1e-12);
    const auto stems = synth::randomStems(n, 15.0, seed);
    Scene s;
    s.tgt_means.resize(n, 3);
    s.tgt_covs.resize(n, 9);
    for (int i = 0; i < n; ++i) {
        s.tgt_means.row(i) << stems[i].x, stems[i].y, 1.3;
        Eigen::Matrix3d c = Eigen::Vector3d(0.01 + 0.02 * (i % 3), 0.012, 1.2).asDiagonal();
        c(0, 1) = c(1, 0) = 0.004 * ((i % 2) ? 1 : -1);
        s.tgt_covs.row(i) = Eigen::Map<Eigen::Matrix<double, 1, 9>>(c.data());
    }
    s.src_means = transformPoints(T.inverse(), s.tgt_means);
    s.src_covs.resize(n, 9);
    for (int i = 0; i < n; ++i) {
        if (noise > 0) s.src_means.row(i).head<2>() += Eigen::RowVector2d(g(rng), g(rng));
        Eigen::Matrix3d c = Eigen::Map<const Eigen::Matrix3d>(s.tgt_covs.row(i).data());
        const Eigen::Matrix3d R = T.linear().transpose();
        Eigen::Matrix3d cs = R * c * R.transpose();
        s.src_covs.row(i) = Eigen::Map<Eigen::Matrix<double, 1, 9>>(cs.data());
    }
    return s;
}

std::vector<std::pair<int, int>> identityPairs(int n) {
    std::vector<std::pair<int, int>> p;
    for (int i = 0; i < n; ++i) p.emplace_back(i, i);
    return p;
}

struct NumericCost {
    const Scene *s;
    std::vector<std::pair<int, int>> pairs;
    bool operator()(const double *x, double *cost) const {
        *cost = registration::shapeCost(x, s->src_means, s->src_covs, s->tgt_means, s->tgt_covs,
                                        pairs, 0.05, nullptr);
        return true;
    }
};

}  // namespace

TEST(ShapeRegistration, AutodiffGradientMatchesNumeric) {
    const Pose3 T = registration::planarToPose(0.7, -0.4, 0.15);
    const Scene s = makeScene(8, T, 0.0, 3);
    const auto pairs = identityPairs(8);
    ceres::NumericDiffFirstOrderFunction<NumericCost, ceres::CENTRAL, 3> numeric(
        new NumericCost{&s, pairs});
    for (const Eigen::Vector3d x :
         {Eigen::Vector3d(0.6, -0.3, 0.12), Eigen::Vector3d(0.75, -0.45, 0.17),
          Eigen::Vector3d(0.5, -0.2, 0.1)}) {
        double grad[3], ngrad[3], cost, ncost;
        cost = registration::shapeCost(x.data(), s.src_means, s.src_covs, s.tgt_means, s.tgt_covs,
                                       pairs, 0.05, grad);
        numeric.Evaluate(x.data(), &ncost, ngrad);
        EXPECT_NEAR(cost, ncost, 1e-12);
        for (int k = 0; k < 3; ++k)
            EXPECT_NEAR(grad[k], ngrad[k], 1e-6 * (1.0 + std::abs(ngrad[k])));
        EXPECT_GT(std::abs(grad[0]) + std::abs(grad[1]) + std::abs(grad[2]),
                  1e-3);  // not at the optimum
    }
}

TEST(ShapeRegistration, RecoversKnownPlanarPose) {
    const Pose3 T = registration::planarToPose(0.8, -0.5, 0.1);
    const Scene s = makeScene(12, T, 0.0, 5);
    const Pose3 init = registration::planarToPose(0.6, -0.3, 0.05);
    const auto pairs = registration::matchTrees(s.src_means, s.tgt_means, init, 1.0);
    ASSERT_GE(pairs.size(), 10u);
    const registration::RegistrationResult r =
        registration::registerShapes(s.src_means, s.src_covs, s.tgt_means, s.tgt_covs, pairs, init);
    const Eigen::Vector3d est = registration::poseToPlanar(Pose3(r.T_target_source));
    EXPECT_NEAR(est.x(), 0.8, 0.01);
    EXPECT_NEAR(est.y(), -0.5, 0.01);
    EXPECT_NEAR(est.z(), 0.1, 0.1 * M_PI / 180.0);
    EXPECT_FALSE(r.degenerate);
    EXPECT_EQ(r.inliers, static_cast<int>(pairs.size()));
    EXPECT_GT(r.covariance(0, 0), 0.0);
    EXPECT_LT(r.covariance(0, 0), 0.01);
    EXPECT_DOUBLE_EQ(r.covariance(2, 2), registration::kUnobservedVariance);
}

TEST(ShapeRegistration, ConsensusRejectsWrongPairs) {
    const Pose3 T = registration::planarToPose(1.0, 0.3, -0.2);
    const Scene s = makeScene(10, T, 0.02, 9);
    auto pairs = identityPairs(10);
    // Three wrong pairs (rotated indices) among ten.
    pairs[0].second = 1;
    pairs[1].second = 2;
    pairs[2].second = 0;
    const registration::RegistrationResult r = registration::registerShapes(
        s.src_means, s.src_covs, s.tgt_means, s.tgt_covs, pairs, Pose3::Identity());
    const Eigen::Vector3d est = registration::poseToPlanar(Pose3(r.T_target_source));
    EXPECT_EQ(r.inliers, 7);
    EXPECT_NEAR(est.x(), 1.0, 0.05);
    EXPECT_NEAR(est.y(), 0.3, 0.05);
    EXPECT_NEAR(est.z(), -0.2, 0.01);
}

TEST(ShapeRegistration, TwoOrFewerStemsAreDegenerate) {
    const Pose3 T = registration::planarToPose(0.3, 0.1, 0.05);
    for (int n : {0, 1, 2}) {
        const Scene s = makeScene(std::max(n, 1), T, 0.0, 11);
        const auto pairs = identityPairs(n);
        const registration::RegistrationResult r = registration::registerShapes(
            s.src_means, s.src_covs, s.tgt_means, s.tgt_covs, pairs, T);
        EXPECT_TRUE(r.degenerate) << n << " stems";
        EXPECT_LE(r.inliers, n);
    }
    const Scene s = makeScene(3, T, 0.0, 11);
    const registration::RegistrationResult r = registration::registerShapes(
        s.src_means, s.src_covs, s.tgt_means, s.tgt_covs, identityPairs(3), T);
    EXPECT_FALSE(r.degenerate);
}

TEST(ShapeRegistration, InvalidInputThrows) {
    const Scene s = makeScene(6, registration::planarToPose(0.5, -0.3, 0.1), 0.0, 7);
    // A pair beyond the stems and a covariance table of the wrong length are errors, not
    // silently skipped pairs.
    auto out_of_range = identityPairs(6);
    out_of_range.emplace_back(6, 0);
    EXPECT_THROW(registration::registerShapes(s.src_means, s.src_covs, s.tgt_means, s.tgt_covs,
                                              out_of_range, Pose3::Identity()),
                 std::invalid_argument);
    EXPECT_THROW(
        registration::consensusPairs(s.src_means, s.tgt_means, {{0, 9}}, Pose3::Identity(), {}),
        std::invalid_argument);
    const registration::Covariances short_covs = s.src_covs.topRows(5);
    EXPECT_THROW(registration::registerShapes(s.src_means, short_covs, s.tgt_means, s.tgt_covs,
                                              identityPairs(5), Pose3::Identity()),
                 std::invalid_argument);
    const double pose[3] = {0.0, 0.0, 0.0};
    EXPECT_THROW(registration::shapeCost(pose, s.src_means, s.src_covs, s.tgt_means,
                                         short_covs.topRows(3), identityPairs(3), 0.05, nullptr),
                 std::invalid_argument);
}
