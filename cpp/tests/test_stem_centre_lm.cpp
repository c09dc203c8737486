#include <gtest/gtest.h>

#include <limits>
#include <stdexcept>

#include "forestslam/features/dog_keypoints.hpp"
#include "forestslam/features/virtual_features.hpp"
#include "forestslam/registration/stem_centre_lm.hpp"
#include "tls_scene.hpp"

using namespace forestslam;

namespace {

double rotationErrorDeg(const Pose3 &a, const Pose3 &b) {
    const Eigen::Matrix3d d = a.linear().transpose() * b.linear();
    return Eigen::AngleAxisd(d).angle() * 180.0 / M_PI;
}

struct Frame {
    features::VirtualFeatures vf;
    features::DogKeypoints kp;
};

Frame makeFrame(const test::Scene &scene, const Pose3 &T_world_sensor) {
    std::vector<std::uint16_t> rings;
    const Points3 scan = test::raycast(scene, T_world_sensor, rings, 16, 0.2, 40.0, 0.003);
    return {features::extractVirtualFeaturesRings(scan, rings), features::detectDogKeypoints(scan)};
}

}  // namespace

TEST(StemCentreLm, RecoversKnownSixDofPerturbation) {
    const auto scene = test::defaultScene();
    const registration::StemCentreTarget target(test::denseMap(scene, 14.0, 0.04));
    const Pose3 T_true = test::makePose(0.6, -0.4, 0.2, 0.02, -0.015, 0.3);
    const Frame f = makeFrame(scene, T_true);
    ASSERT_GE(f.vf.stems.rows(), 3);
    const Pose3 delta = test::makePose(0.2, -0.15, 0.08, 0.015, 0.01, 0.04);
    const Pose3 T_init = delta * T_true;
    const auto r =
        registration::registerStemCentreLm(target, f.vf.centres, f.vf.radii, f.kp.points, T_init);
    EXPECT_TRUE(r.converged);
    EXPECT_FALSE(r.degenerate);
    EXPECT_GT(r.virtual_inliers, 10);
    EXPECT_GT(r.real_inliers, 50);
    EXPECT_LT((r.T_target_source.translation() - T_true.translation()).norm(), 0.01);
    EXPECT_LT(rotationErrorDeg(r.T_target_source, T_true), 0.1);
    EXPECT_LT(r.virtual_rms_m, 0.02);
    // Covariance is a proper (symmetric positive definite) 6x6 with sub-cm standard deviations.
    const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(r.covariance);
    EXPECT_GT(eig.eigenvalues().minCoeff(), 0.0);
    EXPECT_LT(std::sqrt(r.covariance(0, 0)), 0.01);
}

TEST(StemCentreLm, FrameWithoutStemsRegistersOnRealFeatures) {
    const auto scene = test::defaultScene(false);
    const registration::StemCentreTarget target(test::denseMap(scene, 14.0, 0.04));
    const Pose3 T_true = test::makePose(-0.5, 0.8, 0.1, -0.01, 0.02, -0.6);
    const Frame f = makeFrame(scene, T_true);
    EXPECT_EQ(f.vf.centres.rows(), 0);
    const Pose3 delta = test::makePose(0.15, 0.1, -0.05, 0.01, -0.01, 0.03);
    const auto r = registration::registerStemCentreLm(target, f.vf.centres, f.vf.radii, f.kp.points,
                                                      delta * T_true);
    EXPECT_TRUE(r.converged);
    EXPECT_EQ(r.virtual_inliers, 0);
    EXPECT_LT((r.T_target_source.translation() - T_true.translation()).norm(), 0.02);
    EXPECT_LT(rotationErrorDeg(r.T_target_source, T_true), 0.2);
}

TEST(StemCentreLm, TooFewFeaturesIsDegenerateAndKeepsInitialGuess) {
    const auto scene = test::defaultScene();
    const registration::StemCentreTarget target(test::denseMap(scene, 6.0, 0.1));
    const Pose3 T_init = test::makePose(1.0, 2.0, 0.0, 0.0, 0.0, 0.1);
    const auto r = registration::registerStemCentreLm(target, Points3(0, 3), Eigen::VectorXd(0),
                                                      Points3(0, 3), T_init);
    EXPECT_FALSE(r.converged);
    EXPECT_TRUE(r.degenerate);
    EXPECT_TRUE(r.T_target_source.isApprox(T_init));
    const registration::StemCentreTarget empty(Points3(0, 3));
    Points3 one(1, 3);
    one << 0.0, 0.0, 0.0;
    const auto e =
        registration::registerStemCentreLm(empty, one, Eigen::VectorXd::Ones(1), one, T_init);
    EXPECT_FALSE(e.converged);
    EXPECT_TRUE(e.degenerate);
}

namespace {

// A spinning frame taken while the sensor vibrates (roll, pitch and height change within the
// sweep): the sweep (0.1 s, azimuth 0 at tau = -0.05 s) ray-cast in 72 azimuth sectors, each
// from the pose at its time; points in the sensor frame of their time, with rings and times.
struct VibratingFrame {
    Points3 points;
    std::vector<std::uint16_t> rings;
    Eigen::VectorXd times;
};

Pose3 vibratingPose(const Pose3 &T_mid, double tau) {
    const double w = 2 * M_PI * 5.0;  // 5 Hz
    const double roll = 0.0175 * std::sin(w * tau + 0.4);
    const double pitch = 0.0175 * std::sin(w * tau + 2.0);
    const double dz = 0.01 * std::sin(w * tau + 1.0);
    return T_mid * test::makePose(0.0, 0.0, dz, roll, pitch, 0.0);
}

double sweepTime(double x, double y) {
    double az = std::atan2(y, x);
    if (az < 0) az += 2 * M_PI;
    return (az / (2 * M_PI) - 0.5) * 0.1;
}

VibratingFrame vibratingFrame(const test::Scene &scene, const Pose3 &T_mid) {
    VibratingFrame f;
    std::vector<Eigen::Vector3d> pts;
    std::vector<double> ts;
    const int sectors = 72;
    for (int s = 0; s < sectors; ++s) {
        const double tau = ((s + 0.5) / sectors - 0.5) * 0.1;
        std::vector<std::uint16_t> rings;
        const Points3 scan =
            test::raycast(scene, vibratingPose(T_mid, tau), rings, 16, 0.2, 40.0, 0.003, 11 + s);
        for (Eigen::Index i = 0; i < scan.rows(); ++i) {
            double az = std::atan2(scan(i, 1), scan(i, 0));
            if (az < 0) az += 2 * M_PI;
            if (static_cast<int>(az / (2 * M_PI) * sectors) != s) continue;
            pts.emplace_back(scan.row(i).transpose());
            f.rings.push_back(rings[static_cast<std::size_t>(i)]);
            ts.push_back(sweepTime(scan(i, 0), scan(i, 1)));
        }
    }
    f.points.resize(static_cast<Eigen::Index>(pts.size()), 3);
    f.times.resize(static_cast<Eigen::Index>(ts.size()));
    for (std::size_t i = 0; i < pts.size(); ++i) {
        f.points.row(static_cast<Eigen::Index>(i)) = pts[i].transpose();
        f.times[static_cast<Eigen::Index>(i)] = ts[i];
    }
    return f;
}

Eigen::VectorXd featureTimes(const Points3 &features) {
    Eigen::VectorXd t(features.rows());
    for (Eigen::Index i = 0; i < features.rows(); ++i)
        t[i] = sweepTime(features(i, 0), features(i, 1));
    return t;
}

// The features of a vibrating frame taken at T_mid, with their times within the sweep.
struct VibratingFeatures {
    features::VirtualFeatures vf;
    features::DogKeypoints kp;
    registration::SweepTimes times;
};

VibratingFeatures vibratingFeatures(const test::Scene &scene, const Pose3 &T_mid) {
    const VibratingFrame f = vibratingFrame(scene, T_mid);
    VibratingFeatures out{features::extractVirtualFeaturesRings(f.points, f.rings),
                          features::detectDogKeypoints(f.points),
                          {}};
    out.times = {featureTimes(out.vf.centres), featureTimes(out.kp.points)};
    return out;
}

}  // namespace

TEST(StemCentreLm, SweepMotionOfAVibratingFrameIsRecovered) {
    const auto scene = test::defaultScene();
    const registration::StemCentreTarget target(test::denseMap(scene, 14.0, 0.04));
    const Pose3 T_mid = test::makePose(0.6, -0.4, 0.2, 0.0, 0.0, 0.3);
    const auto [vf, kp, times] = vibratingFeatures(scene, T_mid);  // C++17: not capturable
    ASSERT_GE(vf.stems.rows(), 3);
    const Pose3 T_init = test::makePose(0.05, -0.04, 0.02, 0.004, 0.003, 0.01) * T_mid;
    registration::StemCentreLmConfig cfg;
    const auto rigid =
        registration::registerStemCentreLm(target, vf.centres, vf.radii, kp.points, T_init, cfg);
    cfg.sweep_order = 2;
    const auto sweep = registration::registerStemCentreLm(target, vf.centres, vf.radii, kp.points,
                                                          T_init, cfg, &times);
    ASSERT_TRUE(sweep.converged);
    EXPECT_FALSE(sweep.degenerate);
    ASSERT_EQ(sweep.sweep.rows(), 2);
    // The sensor's true in-sweep motion, seen at the ends of the sweep: the estimate puts the
    // keypoints where the true motion puts them, far better than the rigid frame does.
    double rigid_err = 0.0, sweep_err = 0.0, motion = 0.0;
    for (Eigen::Index i = 0; i < kp.points.rows(); ++i) {
        const double tau = times.real[i];
        const Eigen::Vector3d p = kp.points.row(i).transpose();
        const Eigen::Vector3d truth = vibratingPose(T_mid, tau) * p;
        const Eigen::Vector3d at_mid = T_mid * p;
        const Eigen::Vector3d r =
            rigid.T_target_source.linear() * p + rigid.T_target_source.translation();
        const Eigen::Matrix3d R = sweep.T_target_source.linear();
        const Eigen::Vector3d o = sweep.T_target_source.translation();
        Eigen::Matrix<double, 6, 1> c =
            tau * sweep.sweep.row(0).transpose() + tau * tau * sweep.sweep.row(1).transpose();
        const Eigen::Vector3d w = c.tail<3>();
        Eigen::Vector3d q = R * p;
        if (w.norm() > 0) q = Eigen::AngleAxisd(w.norm(), w.normalized()) * q;
        q += o + c.head<3>();
        rigid_err += (r - truth).squaredNorm();
        sweep_err += (q - truth).squaredNorm();
        motion += (at_mid - truth).squaredNorm();
    }
    const double n = static_cast<double>(kp.points.rows());
    rigid_err = std::sqrt(rigid_err / n);
    sweep_err = std::sqrt(sweep_err / n);
    motion = std::sqrt(motion / n);
    std::printf("in-sweep motion %.4f m, rigid LM %.4f m, sweep LM %.4f m (RMS at keypoints)\n",
                motion, rigid_err, sweep_err);
    EXPECT_GT(motion, 0.05);
    EXPECT_LT(sweep_err, 0.4 * rigid_err);
    EXPECT_LT(sweep_err, 0.02);
    EXPECT_LT((sweep.T_target_source.translation() - T_mid.translation()).norm(), 0.02);
}

TEST(StemCentreLm, SweepOrderNeedsOneTimePerFeature) {
    const auto scene = test::defaultScene();
    const registration::StemCentreTarget target(test::denseMap(scene, 14.0, 0.04));
    const Pose3 T_true = test::makePose(0.6, -0.4, 0.2, 0.02, -0.015, 0.3);
    const Frame f = makeFrame(scene, T_true);
    const auto n_c = f.vf.centres.rows(), n_r = f.kp.points.rows();
    registration::StemCentreLmConfig cfg;
    cfg.sweep_order = 2;
    // No times, or a time missing: an error, not a silently rigid registration.
    EXPECT_THROW(registration::registerStemCentreLm(target, f.vf.centres, f.vf.radii, f.kp.points,
                                                    T_true, cfg),
                 std::invalid_argument);
    const registration::SweepTimes short_real{Eigen::VectorXd::Zero(n_c),
                                              Eigen::VectorXd::Zero(n_r - 1)};
    EXPECT_THROW(registration::registerStemCentreLm(target, f.vf.centres, f.vf.radii, f.kp.points,
                                                    T_true, cfg, &short_real),
                 std::invalid_argument);
    // A rigid registration ignores times.
    cfg.sweep_order = 0;
    const auto r = registration::registerStemCentreLm(target, f.vf.centres, f.vf.radii, f.kp.points,
                                                      T_true, cfg, &short_real);
    EXPECT_TRUE(r.converged);
    EXPECT_EQ(r.sweep.rows(), 0);
    EXPECT_LT((r.T_target_source.translation() - T_true.translation()).norm(), 0.01);
}

TEST(StemCentreLm, InvalidInputThrows) {
    const auto scene = test::defaultScene();
    const registration::StemCentreTarget target(test::denseMap(scene, 6.0, 0.1));
    Points3 centres(2, 3);
    centres << 1.0, 0.0, 1.3, 0.0, 2.0, 1.3;
    // One radius for two centres: an error, not a registration on the first centre only.
    EXPECT_THROW(
        registration::registerStemCentreLm(target, centres, Eigen::VectorXd::Constant(1, 0.2),
                                           Points3(0, 3), Pose3::Identity()),
        std::invalid_argument);
    Pose3 nan = Pose3::Identity();
    nan.translation().y() = std::numeric_limits<double>::quiet_NaN();
    EXPECT_THROW(registration::registerStemCentreLm(
                     target, centres, Eigen::VectorXd::Constant(2, 0.2), Points3(0, 3), nan),
                 std::invalid_argument);
}

namespace {

void expectSameResult(const registration::StemCentreLmResult &a,
                      const registration::StemCentreLmResult &b) {
    EXPECT_TRUE(a.T_target_source.matrix() == b.T_target_source.matrix());
    EXPECT_TRUE(a.covariance == b.covariance);
    EXPECT_TRUE(a.sweep == b.sweep);
    EXPECT_EQ(a.converged, b.converged);
    EXPECT_EQ(a.degenerate, b.degenerate);
    EXPECT_EQ(a.iterations, b.iterations);
    EXPECT_EQ(a.virtual_inliers, b.virtual_inliers);
    EXPECT_EQ(a.real_inliers, b.real_inliers);
    EXPECT_EQ(a.virtual_rms_m, b.virtual_rms_m);
    EXPECT_EQ(a.real_rms_m, b.real_rms_m);
}

}  // namespace

// A frame's calls as the TLS pipeline makes them, with one cache and without: the rigid LM
// (coarse gates), the in-sweep LM from its result (fine gates), a fallback from another pose
// (coarse gates again: wider than the kept candidates), then another target. Bit-identical.
TEST(StemCentreLm, CacheGivesTheSameResults) {
    const auto scene = test::defaultScene();
    const registration::StemCentreTarget target(test::denseMap(scene, 14.0, 0.04));
    const registration::StemCentreTarget other(test::denseMap(scene, 12.0, 0.05));
    const Pose3 T_mid = test::makePose(0.6, -0.4, 0.2, 0.0, 0.0, 0.3);
    const VibratingFeatures frame = vibratingFeatures(scene, T_mid);
    const auto &vf = frame.vf;
    const auto &kp = frame.kp;
    const auto &times = frame.times;
    ASSERT_GE(vf.stems.rows(), 3);
    registration::StemCentreLmCache cache;
    const auto both = [&](const registration::StemCentreTarget &t, const Pose3 &T,
                          const registration::StemCentreLmConfig &cfg) {
        const auto fresh =
            registration::registerStemCentreLm(t, vf.centres, vf.radii, kp.points, T, cfg, &times);
        const auto cached = registration::registerStemCentreLm(t, vf.centres, vf.radii, kp.points,
                                                               T, cfg, &times, &cache);
        expectSameResult(fresh, cached);
        return cached;
    };
    registration::StemCentreLmConfig rigid;
    const auto r =
        both(target, test::makePose(0.12, -0.1, 0.03, 0.006, 0.004, 0.04) * T_mid, rigid);
    EXPECT_TRUE(r.converged);
    registration::StemCentreLmConfig sweep;
    sweep.sweep_order = 2;
    sweep.coarse_gate_factor = 1.0;
    both(target, r.T_target_source, sweep);
    both(target, test::makePose(-0.3, 0.25, -0.05, -0.01, 0.008, -0.06) * T_mid, rigid);
    both(other, r.T_target_source, rigid);
    both(other, r.T_target_source, sweep);
}
