#include <gtest/gtest.h>

#include <cmath>

#include "forestslam/sim/ray_primitives.hpp"

using namespace forestslam::sim;

namespace {
Ray makeRay(Eigen::Vector3d o, Eigen::Vector3d d, uint64_t key = 0) {
    Ray r;
    r.origin = o;
    r.dir = d.normalized();
    r.key = key;
    return r;
}
Stem verticalStem(double x, double y, double radius) {
    Stem s;
    s.base = {x, y, 0.0};
    s.shear = {0.0, 0.0};
    s.semi_a = s.semi_b = radius;
    s.height = 20.0;
    return s;
}
}  // namespace

TEST(RayPrimitives, RayAgainstVerticalCylinderGivesExactRange) {
    const Stem s = verticalStem(5.0, 0.0, 0.2);
    Hit hit;
    ASSERT_TRUE(intersectStem(s, makeRay({0, 0, 1.3}, {1, 0, 0}), kInf, hit));
    EXPECT_NEAR(hit.t, 4.8, 1e-9);
    EXPECT_NEAR(hit.cos_incidence, 1.0, 1e-9);
    // Off-axis ray: chord geometry, t = 5 - sqrt(r^2 - y^2).
    ASSERT_TRUE(intersectStem(s, makeRay({0, 0.1, 1.3}, {1, 0, 0}), kInf, hit));
    EXPECT_NEAR(hit.t, 5.0 - std::sqrt(0.04 - 0.01), 1e-9);
    // A ray passing beside it misses, and so does one beyond t_max.
    EXPECT_FALSE(intersectStem(s, makeRay({0, 0.21, 1.3}, {1, 0, 0}), kInf, hit));
    EXPECT_FALSE(intersectStem(s, makeRay({0, 0, 1.3}, {1, 0, 0}), 4.0, hit));
    // Above the top or below the buried bottom: nothing.
    EXPECT_FALSE(intersectStem(s, makeRay({0, 0, 20.5}, {1, 0, 0}), kInf, hit));
    EXPECT_FALSE(intersectStem(s, makeRay({0, 0, -0.5}, {1, 0, 0}), kInf, hit));
}

TEST(RayPrimitives, TaperEllipseAndLeanFollowTheModel) {
    Stem s = verticalStem(5.0, 0.0, 0.2);
    s.taper = 0.025;  // radius 0.2 * (1 - 0.025 (h - 1.3))
    Hit hit;
    ASSERT_TRUE(intersectStem(s, makeRay({0, 0, 2.3}, {1, 0, 0}), kInf, hit));
    EXPECT_NEAR(hit.t, 5.0 - 0.2 * (1 - 0.025), 1e-9);
    ASSERT_TRUE(intersectStem(s, makeRay({0, 0, 0.3}, {1, 0, 0}), kInf, hit));
    EXPECT_NEAR(hit.t, 5.0 - 0.2 * (1 + 0.025), 1e-9);

    Stem e = verticalStem(5.0, 0.0, 0.2);
    e.semi_a = 0.25;
    e.semi_b = 0.15;
    e.angle = 0.0;
    ASSERT_TRUE(intersectStem(e, makeRay({0, 0, 1.3}, {1, 0, 0}), kInf, hit));
    EXPECT_NEAR(hit.t, 4.75, 1e-9);
    ASSERT_TRUE(intersectStem(e, makeRay({5, -5, 1.3}, {0, 1, 0}), kInf, hit));
    EXPECT_NEAR(hit.t, 4.85, 1e-9);
    e.angle = M_PI / 2;  // a axis now along y
    ASSERT_TRUE(intersectStem(e, makeRay({0, 0, 1.3}, {1, 0, 0}), kInf, hit));
    EXPECT_NEAR(hit.t, 4.85, 1e-9);

    Stem l = verticalStem(5.0, 0.0, 0.2);
    l.shear = {0.05, 0.0};  // centre at x = 5 + 0.05 h
    ASSERT_TRUE(intersectStem(l, makeRay({0, 0, 1.3}, {1, 0, 0}), kInf, hit));
    EXPECT_NEAR(hit.t, 5.0 + 0.05 * 1.3 - 0.2, 1e-9);
    ASSERT_TRUE(intersectStem(l, makeRay({0, 0, 10.0}, {1, 0, 0}), kInf, hit));
    EXPECT_NEAR(hit.t, 5.0 + 0.5 - 0.2, 1e-9);
}

TEST(RayPrimitives, BarkRoughnessStaysWithinItsAmplitudeAndAveragesOut) {
    Stem s = verticalStem(0.0, 0.0, 0.2);
    s.bark_amp = 0.004;
    s.phase[0] = 0.3;
    s.phase[1] = 1.1;
    s.phase[2] = 2.0;
    s.phase[3] = 4.0;
    const int n = 720;
    double sum = 0.0, lo = kInf, hi = -kInf;
    for (int i = 0; i < n; ++i) {
        const double az = 2 * M_PI * i / n;
        const Eigen::Vector3d dir(std::cos(az), std::sin(az), 0.0);
        Hit hit;
        ASSERT_TRUE(
            intersectStem(s, makeRay(Eigen::Vector3d(0, 0, 1.3) - 5.0 * dir, dir), kInf, hit));
        const double radius = 5.0 - hit.t;
        sum += radius;
        lo = std::min(lo, radius);
        hi = std::max(hi, radius);
    }
    EXPECT_GE(lo, 0.2 - 0.004 - 1e-6);
    EXPECT_LE(hi, 0.2 + 0.004 + 1e-6);
    EXPECT_GT(hi - lo, 0.003);        // it is rough
    EXPECT_NEAR(sum / n, 0.2, 2e-4);  // zero mean: DBH is the smooth diameter
}

TEST(RayPrimitives, BarkHitsLieOnTheModelledSurface) {
    // Leaning, tapered, rough stem hit by rays at many azimuths and elevations: the hit point's
    // distance from the axis equals r s(h) + bark_amp n(azimuth, h) (Stem::barkNoise).
    Stem s = verticalStem(1.0, -2.0, 0.15);
    s.taper = 0.02;
    s.shear = {0.03, -0.02};
    s.bark_amp = 0.005;
    for (int k = 0; k < 4; ++k) s.phase[k] = 0.7 + 1.3 * k;
    const StemCoeffs coeffs(s);
    int hits = 0;
    for (int i = 0; i < 400; ++i) {
        const double az = 2 * M_PI * i / 400.0, el = -0.4 + 0.8 * (i % 17) / 16.0;
        const double h_aim = 0.5 + 0.02 * i;
        const Eigen::Vector3d centre(1.0 + 0.03 * h_aim, -2.0 - 0.02 * h_aim, h_aim);
        const Eigen::Vector3d dir(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az),
                                  std::sin(el));
        const Eigen::Vector3d offset(0, 0.03 * (i % 5 - 2), 0);
        const Ray ray = makeRay(centre - 4.0 * dir + offset, dir);
        Hit a, b;
        const bool ha = intersectStem(s, ray, kInf, a);
        ASSERT_EQ(ha, intersectStem(s, coeffs, ray, kInf, b));
        if (!ha) continue;
        ASSERT_EQ(a.t, b.t);
        ++hits;
        const Eigen::Vector3d p = ray.origin + a.t * ray.dir;
        const double dx = p.x() - (1.0 + 0.03 * p.z()), dy = p.y() - (-2.0 - 0.02 * p.z());
        const double expected =
            0.15 * s.radiusScale(p.z()) + 0.005 * s.barkNoise(std::atan2(dy, dx), p.z());
        EXPECT_NEAR(std::hypot(dx, dy), expected, 1e-8) << "ray " << i;
    }
    EXPECT_GT(hits, 300);
}

TEST(RayPrimitives, BarkHitDoesNotDependOnTheCallersRangeLimit) {
    // The ray caster passes its best hit so far as t_max, which depends on the order in which
    // primitives are tested (grid cell size, bins): a stem's hit inside t_max must be the same
    // double whatever t_max is. Rays grazing a rough stem, with t_max just past the hit (short of
    // the inner bark envelope), at the hit and unlimited.
    Stem s = verticalStem(0.0, 0.0, 0.12);
    s.taper = 0.01;
    s.bark_amp = 0.006;
    for (int k = 0; k < 4; ++k) s.phase[k] = 0.3 + 0.9 * k;
    const StemCoeffs coeffs(s);
    int hits = 0;
    for (int i = 0; i < 2000; ++i) {
        const double offset = 0.126 * (i % 200) / 199.0;  // up to the outer bark envelope
        const double h = 0.4 + 0.01 * i;
        const Ray ray = makeRay({-5.0, offset, h}, {1.0, 0.0, 0.0});
        Hit free_hit;
        if (!intersectStem(s, coeffs, ray, kInf, free_hit)) continue;
        ++hits;
        for (const double t_max : {free_hit.t + 1e-4, free_hit.t + 1e-6, free_hit.t}) {
            Hit hit;
            ASSERT_TRUE(intersectStem(s, coeffs, ray, t_max, hit)) << "ray " << i;
            ASSERT_EQ(hit.t, free_hit.t) << "ray " << i << " t_max " << t_max;
            ASSERT_EQ(hit.cos_incidence, free_hit.cos_incidence);
        }
    }
    EXPECT_GT(hits, 1500);
}

TEST(RayPrimitives, CappedCylinder) {
    Cylinder c{{3, -2, 0.2}, {3, 2, 0.2}, 0.2, kLog};
    Hit hit;
    ASSERT_TRUE(intersectCylinder(c, makeRay({0, 0, 0.2}, {1, 0, 0}), kInf, hit));
    EXPECT_NEAR(hit.t, 2.8, 1e-9);
    ASSERT_TRUE(intersectCylinder(c, makeRay({3, -5, 0.2}, {0, 1, 0}), kInf, hit));
    EXPECT_NEAR(hit.t, 3.0, 1e-9);  // end cap
    EXPECT_NEAR(hit.cos_incidence, 1.0, 1e-9);
    EXPECT_FALSE(intersectCylinder(c, makeRay({0, 2.5, 0.2}, {1, 0, 0}), kInf, hit));
}

TEST(RayPrimitives, FoliageTransmissionFollowsBeerLambert) {
    FoliageEllipsoid f{{10, 0, 0}, {1, 1, 1}, 1.0, kFoliage};
    const int n = 20000;
    int hits = 0;
    double depth = 0.0;
    for (int i = 0; i < n; ++i) {
        Hit hit;
        if (intersectFoliage(f, 3, makeRay({0, 0, 0}, {1, 0, 0}, mixKey(42, i)), kInf, hit)) {
            ++hits;
            depth += hit.t - 9.0;
            ASSERT_GE(hit.t, 9.0);
            ASSERT_LE(hit.t, 11.0);
        }
    }
    const double p = 1.0 - std::exp(-2.0);  // chord of 2 m, sigma 1/m
    EXPECT_NEAR(static_cast<double>(hits) / n, p, 0.01);
    // Mean free path truncated to the chord: (1 - 3 e^-2) / (1 - e^-2).
    EXPECT_NEAR(depth / hits, (1.0 - 3.0 * std::exp(-2.0)) / p, 0.02);
    // Same key, same answer.
    Hit a, b;
    const bool ha = intersectFoliage(f, 3, makeRay({0, 0, 0}, {1, 0, 0}, 7), kInf, a);
    const bool hb = intersectFoliage(f, 3, makeRay({0, 0, 0}, {1, 0, 0}, 7), kInf, b);
    EXPECT_EQ(ha, hb);
    if (ha) {
        EXPECT_EQ(a.t, b.t);
    }
}
