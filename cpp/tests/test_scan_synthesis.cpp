#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>

#include "forestslam/sim/scan_synthesis.hpp"

using namespace forestslam;
using namespace forestslam::sim;

namespace {

ForestScene flatGround(double z = 0.0) {
    const int n = 400;  // 200 m x 200 m of 0.5 m cells centred on the origin
    return ForestScene(Heightfield(-100.0, -100.0, 0.5, Eigen::MatrixXd::Constant(n + 1, n + 1, z)),
                       {}, {}, {});
}

PoseRows poseRow(const Eigen::Matrix3d &r, const Eigen::Vector3d &p) {
    Eigen::Matrix4d t = Eigen::Matrix4d::Identity();
    t.topLeftCorner<3, 3>() = r;
    t.topRightCorner<3, 1>() = p;
    PoseRows row(1, 16);
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) row(0, 4 * i + j) = t(i, j);
    return row;
}

// Downward fan of n directions at 20 deg below the horizon, one group each.
Points3 fan(int n) {
    Points3 d(n, 3);
    const double el = -20.0 * M_PI / 180.0;
    for (int i = 0; i < n; ++i) {
        const double az = 2 * M_PI * i / n;
        d.row(i) << std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el);
    }
    return d;
}

}  // namespace

TEST(ScanSynthesis, StaticSensorSeesGroundAtExactRangesWithModelIntensity) {
    const ForestScene scene = flatGround();
    const Points3 dirs = fan(360);
    const IndexVector group = IndexVector::Zero(360);
    const Eigen::VectorXd t0 = Eigen::VectorXd::Zero(1);
    ScanModel model;
    model.materials[kGround] = {40.0, 0.0, 0.0, 1.0};  // no noise: 40 |cos incidence|
    const PoseRows pose = poseRow(Eigen::Matrix3d::Identity(), {0, 0, 1.5});
    const SynthesizedScan s = synthesizeScan(scene, t0, pose, t0, group, dirs, model, 1, 2);
    ASSERT_EQ(s.ray.size(), 360);
    const double range = 1.5 / std::sin(20.0 * M_PI / 180.0);
    for (Eigen::Index k = 0; k < s.ray.size(); ++k) {
        EXPECT_EQ(s.ray[k], k);
        EXPECT_NEAR(s.points.row(k).norm(), range, 1e-9);
        EXPECT_NEAR(s.points(k, 2), -1.5, 1e-9);
        EXPECT_EQ(s.surface[k], kGround);
        // Lambertian ground inside the reference range, cos against the vertical = sin(20 deg),
        // rounded as a driver reports it.
        const double cos_inc = std::sin(20.0 * M_PI / 180.0);
        EXPECT_EQ(s.intensity[k], std::round(40.0 * cos_inc));
    }
}

TEST(ScanSynthesis, GroupsGetInterpolatedPoses) {
    // Two knots 1 s apart: 2 m forward and a 90 deg yaw. The group at 0.5 s fires from (1, 0)
    // at 45 deg yaw, straight at a stem 5 m away (range 4.8); the knots' own rays miss it.
    Stem stem;
    stem.base = {1.0 + 5.0 * std::cos(M_PI / 4), 5.0 * std::sin(M_PI / 4), 0.0};
    stem.shear = {0.0, 0.0};
    stem.semi_a = stem.semi_b = 0.2;
    stem.height = 20.0;
    const ForestScene scene(Heightfield(), {stem}, {}, {});
    PoseRows knots(2, 16);
    knots.row(0) = poseRow(Eigen::Matrix3d::Identity(), {0, 0, 1.3});
    knots.row(1) = poseRow(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()).toRotationMatrix(),
                           {2, 0, 1.3});
    Eigen::VectorXd knot_time(2), group_time(3);
    knot_time << 0.0, 1.0;
    group_time << 0.0, 0.5, 1.0;
    Points3 dirs(3, 3);
    dirs << 1, 0, 0, 1, 0, 0, 1, 0, 0;
    IndexVector group(3);
    group << 0, 1, 2;
    const SynthesizedScan out =
        synthesizeScan(scene, knot_time, knots, group_time, group, dirs, ScanModel(), 0, 0);
    ASSERT_EQ(out.ray.size(), 1);
    EXPECT_EQ(out.ray[0], 1);
    EXPECT_NEAR(out.points(0, 0), 4.8, 1e-9);
    EXPECT_EQ(out.surface[0], kStem);
}

TEST(ScanSynthesis, NoiseAndDropoutFollowTheModelAndTheSeed) {
    const ForestScene scene = flatGround();
    const int n = 20000;
    const Points3 dirs = fan(n);
    const IndexVector group = IndexVector::Zero(n);
    const Eigen::VectorXd t0 = Eigen::VectorXd::Zero(1);
    const PoseRows pose = poseRow(Eigen::Matrix3d::Identity(), {0, 0, 1.0});
    ScanModel model;
    model.range_noise_m = 0.03;
    model.dropout_rate = 0.2;
    const SynthesizedScan a = synthesizeScan(scene, t0, pose, t0, group, dirs, model, 5, 9);
    EXPECT_NEAR(static_cast<double>(a.ray.size()) / n, 0.8, 0.01);
    const double range = 1.0 / std::sin(20.0 * M_PI / 180.0);
    double sum = 0.0, sum2 = 0.0;
    for (Eigen::Index k = 0; k < a.ray.size(); ++k) {
        const double e = a.points.row(k).norm() - range;
        sum += e;
        sum2 += e * e;
    }
    const double mean = sum / a.ray.size(), sd = std::sqrt(sum2 / a.ray.size() - mean * mean);
    EXPECT_NEAR(mean, 0.0, 0.002);
    EXPECT_NEAR(sd, 0.03, 0.0015);
    // Same seeds: same scan; another noise seed: other draws.
    const SynthesizedScan b = synthesizeScan(scene, t0, pose, t0, group, dirs, model, 5, 9);
    EXPECT_TRUE(a.ray == b.ray);
    EXPECT_TRUE(a.points == b.points);
    EXPECT_TRUE(a.intensity == b.intensity);
    const SynthesizedScan c = synthesizeScan(scene, t0, pose, t0, group, dirs, model, 5, 10);
    EXPECT_FALSE(c.ray.size() == a.ray.size() && c.points == a.points);
}

TEST(ScanSynthesis, BadInputsThrow) {
    const ForestScene scene = flatGround();
    const Points3 dirs = fan(4);
    const Eigen::VectorXd t0 = Eigen::VectorXd::Zero(1);
    const PoseRows pose = poseRow(Eigen::Matrix3d::Identity(), {0, 0, 1.0});
    IndexVector bad(4);
    bad << 0, 0, 1, 0;  // only one group
    EXPECT_THROW(synthesizeScan(scene, t0, pose, t0, bad, dirs, ScanModel(), 0, 0),
                 std::invalid_argument);
    EXPECT_THROW(synthesizeScan(scene, Eigen::VectorXd(), PoseRows(0, 16), t0, IndexVector::Zero(4),
                                dirs, ScanModel(), 0, 0),
                 std::invalid_argument);
    // No directions: an empty scan.
    EXPECT_EQ(synthesizeScan(scene, t0, pose, t0, IndexVector(), Points3(0, 3), ScanModel(), 0, 0)
                  .ray.size(),
              0);
}

TEST(ScanSynthesis, MaterialIntensityFallsOffWithRangeAndIncidenceOnly) {
    ScanModel model;
    model.materials[kStem] = {40.0, 0.0, 0.0, 1.0};
    model.materials[kFoliage] = {120.0, 0.0, 0.0, 0.0};
    model.reference_range_m = 5.0;
    model.range_exponent = 0.5;
    model.near_range_m = 2.0;
    // Reference range, normal incidence: the median; oblique: times cos; foliage ignores it.
    EXPECT_EQ(returnIntensity(kStem, 3, 4.0, 1.0, 0.0, model), 40.0f);
    EXPECT_EQ(returnIntensity(kStem, 3, 4.0, 0.5, 0.0, model), 20.0f);
    EXPECT_EQ(returnIntensity(kFoliage, 3, 4.0, 0.5, 0.0, model), 120.0f);
    // Beyond the reference: (5 / r)^0.5; near range: down to half at 0 m.
    EXPECT_EQ(returnIntensity(kFoliage, 3, 20.0, 1.0, 0.0, model), 60.0f);
    EXPECT_EQ(returnIntensity(kFoliage, 3, 1.0, 1.0, 0.0, model), 90.0f);
    // Log-normal noise per return and per object, deterministic, clamped to 255.
    model.materials[kStem] = {40.0, 0.5, 0.3, 1.0};
    EXPECT_EQ(returnIntensity(kStem, 3, 4.0, 1.0, 1.0, model),
              returnIntensity(kStem, 3, 4.0, 1.0, 1.0, model));
    double sum = 0.0;
    for (int obj = 0; obj < 4000; ++obj)
        sum += std::log(std::max(1.0f, returnIntensity(kStem, obj, 4.0, 1.0, 0.0, model)) / 40.0);
    EXPECT_NEAR(sum / 4000, 0.0, 0.02);  // median 40 over objects
    EXPECT_EQ(returnIntensity(kStem, 3, 4.0, 1.0, 20.0, model), 255.0f);
}

TEST(ScanSynthesis, DropoutAndRangeNoiseGrowAtGrazingIncidenceAndLongRange) {
    ScanModel model;
    model.range_max_m = 100.0;
    model.range_noise_m = 0.02;
    model.beam_divergence_rad = 0.002;
    model.dropout_rate = 0.1;
    model.grazing_cos = 0.2;
    model.far_fraction = 0.8;
    EXPECT_NEAR(dropoutProbability(10.0, 1.0, model), 0.1, 1e-12);
    EXPECT_NEAR(dropoutProbability(10.0, 0.1, model), 1.0 - 0.9 * 0.5, 1e-12);
    EXPECT_NEAR(dropoutProbability(90.0, 1.0, model), 1.0 - 0.9 * 0.5, 1e-12);
    EXPECT_NEAR(dropoutProbability(100.0, 1.0, model), 1.0, 1e-12);
    EXPECT_NEAR(rangeSigma(10.0, 1.0, model), 0.02, 1e-12);
    const double c = 0.5, fp = 0.5 * 0.002 * 10.0 * std::sqrt(1 - c * c) / c;
    EXPECT_NEAR(rangeSigma(10.0, c, model), std::hypot(0.02, fp), 1e-12);
    EXPECT_NEAR(rangeSigma(10.0, 0.0, model), rangeSigma(10.0, 0.0995, model), 1e-12);
}
