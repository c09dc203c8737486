#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <stdexcept>

#include "forestslam/localization/global_localizer.hpp"

using forestslam::Points2;

namespace {

// A forest-like stand: random positions with a minimum spacing (dart throwing).
Points2 stand(int n, double extent, unsigned seed, double min_spacing = 2.0) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0, extent);
    std::vector<Eigen::Vector2d> pts;
    for (int tries = 0; int(pts.size()) < n && tries < 100000; ++tries) {
        const Eigen::Vector2d p(u(rng), u(rng));
        bool ok = true;
        for (const auto &q : pts) ok = ok && (p - q).norm() >= min_spacing;
        if (ok) pts.push_back(p);
    }
    Points2 xy(pts.size(), 2);
    for (size_t i = 0; i < pts.size(); ++i) xy.row(i) = pts[i].transpose();
    return xy;
}

// Trees within radius of `centre`, seen in a local frame with pose (x, y, yaw) in the map,
// with position noise, missed trees and false trunks.
Points2 observe(const Points2 &map, const Eigen::Vector3d &pose, double radius, double noise,
                double miss, int outliers, unsigned seed) {
    std::mt19937 rng(seed);
    std::normal_distribution<double> g(0, noise);
    std::uniform_real_distribution<double> u(0, 1);
    const double c = std::cos(pose[2]), s = std::sin(pose[2]);
    std::vector<Eigen::Vector2d> out;
    for (Eigen::Index i = 0; i < map.rows(); ++i) {
        const Eigen::Vector2d d = map.row(i).transpose() - pose.head<2>();
        if (d.norm() > radius || u(rng) < miss) continue;
        out.emplace_back(c * d.x() + s * d.y() + g(rng), -s * d.x() + c * d.y() + g(rng));
    }
    for (int k = 0; k < outliers; ++k) {
        const double r = radius * std::sqrt(u(rng)), a = 2 * M_PI * u(rng);
        out.emplace_back(r * std::cos(a), r * std::sin(a));
    }
    Points2 xy(out.size(), 2);
    for (size_t i = 0; i < out.size(); ++i) xy.row(i) = out[i].transpose();
    return xy;
}

}  // namespace

TEST(GlobalLocalizer, FitRigid2DRecoversExactTransform) {
    std::vector<Eigen::Vector2d> a = {{0, 0}, {3, 1}, {-2, 5}, {4, -3}}, b;
    const double yaw = -2.5, c = std::cos(yaw), s = std::sin(yaw);
    for (const auto &p : a) b.emplace_back(c * p.x() - s * p.y() + 7, s * p.x() + c * p.y() - 4);
    const Eigen::Vector3d pose = forestslam::localization::fitRigid2D(a, b);
    EXPECT_NEAR(pose[0], 7, 1e-12);
    EXPECT_NEAR(pose[1], -4, 1e-12);
    EXPECT_NEAR(pose[2], yaw, 1e-12);
}

TEST(GlobalLocalizer, RecoversKnownPoseWithNoiseOutliersAndMissingTrunks) {
    const Points2 map = stand(900, 200, 1);
    const forestslam::localization::TreeMap tree_map(map);
    std::mt19937 rng(2);
    std::uniform_real_distribution<double> u(40, 160), a(-M_PI, M_PI);
    int accepted = 0;
    for (int q = 0; q < 20; ++q) {
        const Eigen::Vector3d truth(u(rng), u(rng), a(rng));
        const Points2 local = observe(map, truth, 20.0, 0.03, 0.2, 4, 100 + q);
        const auto res = tree_map.localize(local);
        if (res.rejected) continue;
        ++accepted;
        EXPECT_NEAR(res.x, truth[0], 0.1);
        EXPECT_NEAR(res.y, truth[1], 0.1);
        EXPECT_NEAR(std::remainder(res.yaw - truth[2], 2 * M_PI), 0.0, 0.01);
        EXPECT_GE(res.inliers, 10);
        EXPECT_GT(res.covariance(0, 0), 0.0);
        EXPECT_LT(std::sqrt(res.covariance(0, 0)), 0.1);
    }
    EXPECT_GE(accepted, 19);
}

TEST(GlobalLocalizer, NoiseFreeRecoveryIsExact) {
    const Points2 map = stand(400, 150, 4);
    const forestslam::localization::TreeMap tree_map(map);
    const Eigen::Vector3d truth(70, 80, 0.7);
    const Points2 local = observe(map, truth, 25.0, 0.0, 0.0, 0, 9);
    const auto res = tree_map.localize(local);
    ASSERT_FALSE(res.rejected) << res.reason;
    EXPECT_NEAR(res.x, truth[0], 1e-9);
    EXPECT_NEAR(res.y, truth[1], 1e-9);
    EXPECT_NEAR(res.yaw, truth[2], 1e-11);
    EXPECT_EQ(res.inliers, int(local.rows()));
}

TEST(GlobalLocalizer, InvariantToTrunkOrder) {
    const Points2 map = stand(600, 180, 5);
    const forestslam::localization::TreeMap tree_map(map);
    const Points2 local = observe(map, {90, 60, -1.2}, 20.0, 0.04, 0.15, 3, 6);
    const auto a = tree_map.localize(local);
    std::vector<int> perm(local.rows());
    for (size_t i = 0; i < perm.size(); ++i) perm[i] = int(i);
    std::shuffle(perm.begin(), perm.end(), std::mt19937(8));
    Points2 shuffled(local.rows(), 2);
    for (size_t i = 0; i < perm.size(); ++i) shuffled.row(i) = local.row(perm[i]);
    const auto b = tree_map.localize(shuffled);
    ASSERT_FALSE(a.rejected);
    ASSERT_FALSE(b.rejected);
    EXPECT_NEAR(a.x, b.x, 1e-9);
    EXPECT_NEAR(a.y, b.y, 1e-9);
    EXPECT_NEAR(a.yaw, b.yaw, 1e-11);
    EXPECT_EQ(a.inliers, b.inliers);
}

TEST(GlobalLocalizer, RejectsAPlaceThatIsNotInTheMap) {
    const Points2 map = stand(900, 200, 1);
    const forestslam::localization::TreeMap tree_map(map);
    const Points2 elsewhere = stand(900, 200, 77);
    for (int q = 0; q < 10; ++q) {
        const Points2 local =
            observe(elsewhere, {50.0 + 10 * q, 100, 0.3 * q}, 20.0, 0.03, 0.1, 2, q);
        EXPECT_TRUE(tree_map.localize(local).rejected) << "query " << q;
    }
}

TEST(GlobalLocalizer, DegenerateQueriesAreRejectedNotThrown) {
    const Points2 map = stand(300, 120, 3);
    const forestslam::localization::TreeMap tree_map(map);
    EXPECT_TRUE(tree_map.localize(Points2(0, 2)).rejected);
    Points2 two(2, 2);
    two << 0, 0, 3, 4;
    EXPECT_TRUE(tree_map.localize(two).rejected);
    Points2 line(8, 2);
    for (int i = 0; i < 8; ++i) line.row(i) << i * 2.0, 1.0;
    const auto collinear = tree_map.localize(line);
    EXPECT_TRUE(collinear.rejected);
    EXPECT_FALSE(collinear.reason.empty());
    Points2 dups(6, 2);
    dups << 1, 1, 1, 1, 1, 1, 5, 5, 5, 5, NAN, 2;
    EXPECT_TRUE(tree_map.localize(dups).rejected);
    // Empty map.
    const forestslam::localization::TreeMap empty(Points2(0, 2));
    EXPECT_TRUE(empty.localize(observe(map, {60, 60, 0}, 20, 0, 0, 0, 1)).rejected);
}

TEST(GlobalLocalizer, ReportsStageSignificanceAndRunnerUp) {
    const Points2 map = stand(600, 150, 3);
    const forestslam::localization::TreeMap tree_map(map);
    const Eigen::Vector3d truth(70, 80, 0.7);
    const auto res = tree_map.localize(observe(map, truth, 20, 0.05, 0.1, 2, 4));
    ASSERT_FALSE(res.rejected) << res.reason;
    EXPECT_EQ(res.stage, forestslam::localization::LocalizationStage::Star);
    EXPECT_STREQ(forestslam::localization::stageName(res.stage), "star");
    EXPECT_GE(res.significance, forestslam::localization::GlobalLocalizerConfig().min_significance);
    EXPECT_LT(res.expected_chance_inliers, 0.25 * res.inliers);
    if (res.runner_up.exists) {
        EXPECT_LT(res.runner_up.significance, res.significance);
        EXPECT_EQ(res.runner_up.inliers, res.second_inliers);
    }
    // No fallback: nothing is ever answered by the triangle stage.
    forestslam::localization::GlobalLocalizerConfig no_fallback;
    no_fallback.triangle_fallback = false;
    const auto small = tree_map.localize(observe(map, truth, 8, 0.03, 0.3, 1, 5), no_fallback);
    EXPECT_NE(small.stage, forestslam::localization::LocalizationStage::Triangle);
}

TEST(GlobalLocalizer, AbsentPlacesAreNotSignificant) {
    const Points2 map = stand(600, 150, 3);
    const Points2 other = stand(600, 150, 77);
    const forestslam::localization::TreeMap tree_map(map);
    for (int q = 0; q < 10; ++q) {
        const Eigen::Vector3d pose(30 + 9 * q, 75, 0.6 * q);
        const auto res = tree_map.localize(observe(other, pose, 20, 0.05, 0.1, 2, 10 + q));
        EXPECT_TRUE(res.rejected) << "query " << q << " significance " << res.significance;
    }
}

TEST(GlobalLocalizer, AFewTightTrunksInASparseMapAreEnough) {
    // 6 trunks seen in a sparse stand (0.01 trunks/m^2): too few for a count in a 0.5 m gate,
    // but they fit within centimetres. Found, with 0 wrong; the same view of another stand is
    // rejected.
    const Points2 map = stand(400, 200, 5, 4.0);
    const Points2 other = stand(400, 200, 55, 4.0);
    const forestslam::localization::TreeMap tree_map(map);
    int found = 0, wrong = 0, absent_accepted = 0;
    for (int q = 0; q < 10; ++q) {
        const Eigen::Vector3d truth(40 + 12 * q, 100, 0.5 * q);
        const auto res = tree_map.localize(observe(map, truth, 14, 0.03, 0.0, 0, 20 + q));
        if (!res.rejected) {
            const bool right = std::hypot(res.x - truth[0], res.y - truth[1]) < 0.3;
            found += right;
            wrong += !right;
        }
        absent_accepted +=
            !tree_map.localize(observe(other, truth, 14, 0.03, 0.0, 0, 40 + q)).rejected;
    }
    EXPECT_GE(found, 8);
    EXPECT_EQ(wrong, 0);
    EXPECT_EQ(absent_accepted, 0);
}

TEST(GlobalLocalizer, TwoCopiesOfAPlaceAreAmbiguous) {
    // The map holds the same patch twice, 100 m apart: both places are significant, so neither
    // is accepted.
    const Points2 patch = stand(60, 40, 9);
    Points2 map(2 * patch.rows(), 2);
    map.topRows(patch.rows()) = patch;
    map.bottomRows(patch.rows()) = patch.rowwise() + Eigen::RowVector2d(100, 0);
    const forestslam::localization::TreeMap tree_map(map);
    const auto res = tree_map.localize(observe(patch, {20, 20, 0.4}, 15, 0.02, 0.1, 0, 3));
    EXPECT_TRUE(res.rejected);
    EXPECT_NE(res.reason.find("ambiguous"), std::string::npos) << res.reason;
    ASSERT_TRUE(res.runner_up.exists);
    EXPECT_NEAR(std::abs(res.runner_up.x - res.x), 100.0, 0.5);
}

TEST(GlobalLocalizer, FitRigid2DNeedsOnePartnerPerPoint) {
    const std::vector<Eigen::Vector2d> a = {{0, 0}, {3, 1}, {-2, 5}}, b = {{0, 0}, {3, 1}};
    EXPECT_THROW(forestslam::localization::fitRigid2D(a, b), std::invalid_argument);
}

TEST(GlobalLocalizer, DbhLengthsMustMatch) {
    Points2 map(40, 2);
    for (int i = 0; i < 40; ++i) map.row(i) << (i % 7) * 3.1 + 0.2 * (i % 3), (i / 7) * 2.9;
    EXPECT_THROW(forestslam::localization::TreeMap(map, 0.01, Eigen::VectorXd::Constant(39, 0.3)),
                 std::invalid_argument);
    const forestslam::localization::TreeMap tree_map(map, 0.01, Eigen::VectorXd::Constant(40, 0.3));
    EXPECT_TRUE(tree_map.hasDbh());
    EXPECT_THROW(tree_map.localize(map, {}, Eigen::VectorXd::Constant(3, 0.3)),
                 std::invalid_argument);
    EXPECT_FALSE(forestslam::localization::TreeMap(map).hasDbh());
}

TEST(GlobalLocalizer, ObservationCountsNeedOnePerTrunkAndOneFrameChangesNothing) {
    Points2 map(400, 2);
    for (int i = 0; i < 400; ++i)
        map.row(i) << (i % 20) * 3.1 + 0.4 * ((i * 7) % 5), (i / 20) * 2.9;
    const forestslam::localization::TreeMap tree_map(map);
    EXPECT_THROW(tree_map.localize(map, {}, {}, Eigen::VectorXi::Constant(3, 2)),
                 std::invalid_argument);
    // Counts of a single frame (all 1) leave every trunk alike: the same answer as no counts,
    // also for a view larger than the fallback's max_fallback_trunks.
    // A place not in the map (both stages run in full), larger than the fallback's 10 trunks.
    forestslam::localization::GlobalLocalizerConfig cfg;
    cfg.max_fallback_trunks = 10;
    for (int n : {12, 60}) {
        Points2 local(n, 2);
        for (int i = 0; i < n; ++i)
            local.row(i) << 2.3 * i - 1.7 * (i * i % 11), 1.9 * (i % 7) + 0.8 * (i * i % 13);
        const auto plain = tree_map.localize(local, cfg);
        const auto counted = tree_map.localize(local, cfg, {}, Eigen::VectorXi::Ones(n));
        EXPECT_EQ(plain.stage, counted.stage);
        EXPECT_EQ(plain.inliers, counted.inliers);
        EXPECT_EQ(plain.hypotheses, counted.hypotheses);
        EXPECT_DOUBLE_EQ(plain.significance, counted.significance);
    }
}
