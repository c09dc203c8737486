#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "forestslam/sim/forest_scene.hpp"

using namespace forestslam;
using namespace forestslam::sim;

namespace {
Eigen::MatrixXd planeGrid(int n, double cell, double x0, double y0, double gx, double gy,
                          double c) {
    Eigen::MatrixXd z(n + 1, n + 1);
    for (int iy = 0; iy <= n; ++iy)
        for (int ix = 0; ix <= n; ++ix)
            z(iy, ix) = c + gx * (x0 + ix * cell) + gy * (y0 + iy * cell);
    return z;
}
Ray makeRay(Eigen::Vector3d o, Eigen::Vector3d d) {
    Ray r;
    r.origin = o;
    r.dir = d.normalized();
    return r;
}
}  // namespace

TEST(ForestScene, FlatGroundAtPredictedRanges) {
    Heightfield hf(-100, -100, 0.5, planeGrid(400, 0.5, -100, -100, 0, 0, 0));
    ForestScene scene(hf, {}, {}, {});
    for (double elev_deg : {-15.0, -7.0, -3.0, -1.0}) {
        for (double az : {0.0, 0.7, 2.0, 4.1}) {
            const double e = elev_deg * M_PI / 180;
            const Ray r = makeRay({0.13, -0.27, 1.0}, {std::cos(e) * std::cos(az),
                                                       std::cos(e) * std::sin(az), std::sin(e)});
            const Hit hit = scene.cast(r);
            ASSERT_TRUE(hit.valid());
            EXPECT_EQ(hit.surface, kGround);
            EXPECT_NEAR(hit.t, 1.0 / std::sin(-e), 1e-9);
            EXPECT_NEAR(hit.cos_incidence, std::sin(-e), 1e-9);
        }
    }
    EXPECT_FALSE(scene.cast(makeRay({0, 0, 1}, {1, 0, 0.01})).valid());
}

TEST(ForestScene, SlopedGroundExactAndHeightAt) {
    const double gx = 0.1, gy = -0.05;
    Heightfield hf(-50, -50, 0.5, planeGrid(200, 0.5, -50, -50, gx, gy, 0.3));
    EXPECT_NEAR(hf.heightAt(3.3, -7.7), 0.3 + gx * 3.3 + gy * -7.7, 1e-12);
    EXPECT_TRUE(std::isnan(hf.heightAt(60, 0)));
    ForestScene scene(hf, {}, {}, {});
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> az(0, 2 * M_PI), el(-0.5, -0.05);
    for (int i = 0; i < 200; ++i) {
        const double a = az(rng), e = el(rng);
        const Eigen::Vector3d d(std::cos(e) * std::cos(a), std::cos(e) * std::sin(a), std::sin(e));
        const Eigen::Vector3d o(1.0, 2.0, 0.3 + gx * 1.0 + gy * 2.0 + 1.5);
        const Hit hit = scene.cast(makeRay(o, d));
        if (!hit.valid()) continue;  // left the 100 m grid
        const Eigen::Vector3d p = o + hit.t * d;
        EXPECT_NEAR(p.z(), 0.3 + gx * p.x() + gy * p.y(), 1e-9);
    }
}

TEST(ForestScene, FirstHitOccludesAndRangeMinBlocks) {
    Stem a;
    a.base = {5, 0, 0};
    a.shear = {0, 0};
    a.semi_a = a.semi_b = 0.2;
    Stem b = a;
    b.base = {9, 0, 0};
    b.semi_a = b.semi_b = 0.4;
    ForestScene scene(Heightfield(), {b, a}, {}, {});
    const Hit hit = scene.cast(makeRay({0, 0, 1.3}, {1, 0, 0}));
    ASSERT_TRUE(hit.valid());
    EXPECT_EQ(hit.object, 1);
    EXPECT_NEAR(hit.t, 4.8, 1e-9);
    Points3 o(1, 3), d(2, 3);
    o << 0, 0, 1.3;
    d << 1, 0, 0, -1, 0, 0;
    const CastResult r = scene.castRays(o, d, 5.0, 100.0, 1);
    EXPECT_TRUE(std::isnan(r.range[0]));  // the near stem blocks, and it is closer than range_min
    EXPECT_TRUE(std::isnan(r.range[1]));  // nothing behind
}

TEST(ForestScene, GridMatchesBruteForce) {
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(-20, 20), r(0.05, 0.4), h(5, 25), s(-0.05, 0.05);
    std::vector<Stem> stems;
    std::vector<Cylinder> cyl;
    std::vector<FoliageEllipsoid> fol;
    for (int i = 0; i < 60; ++i) {
        Stem st;
        st.base = {u(rng), u(rng), 0.0};
        st.shear = {s(rng), s(rng)};
        st.semi_a = r(rng);
        st.semi_b = st.semi_a * 0.9;
        st.angle = u(rng);
        st.taper = 0.01;
        st.height = h(rng);
        st.bark_amp = 0.003;
        stems.push_back(st);
        cyl.push_back({st.base + Eigen::Vector3d(0, 0, 2), st.base + Eigen::Vector3d(1.0, 0.3, 2.2),
                       0.02, kBranch});
        fol.push_back({st.base + Eigen::Vector3d(0, 0, st.height), {2, 2, 3}, 0.8, kFoliage});
    }
    Heightfield hf(-40, -40, 0.5, planeGrid(160, 0.5, -40, -40, 0.02, 0.01, 0));
    ForestScene grid(hf, stems, cyl, fol, 2.0);
    ForestScene brute(hf, stems, cyl, fol, 1000.0);
    std::uniform_real_distribution<double> az(0, 2 * M_PI), el(-0.4, 0.6);
    const int n = 3000;
    Points3 o(1, 3), d(n, 3);
    o << 0.5, 0.5, 1.5;
    for (int i = 0; i < n; ++i) {
        const double a = az(rng), e = el(rng);
        d.row(i) << std::cos(e) * std::cos(a), std::cos(e) * std::sin(a), std::sin(e);
    }
    const CastResult rg = grid.castRays(o, d, 0.5, 100.0, 9);
    const CastResult rb = brute.castRays(o, d, 0.5, 100.0, 9);
    int kinds[7] = {0};
    for (int i = 0; i < n; ++i) {
        ASSERT_EQ(std::isnan(rg.range[i]), std::isnan(rb.range[i])) << i;
        if (std::isnan(rg.range[i])) continue;
        // Rough bark can cross a ray more than once inside its band; bisection may then
        // pick another crossing, so agree to 10 um, not to round-off.
        EXPECT_NEAR(rg.range[i], rb.range[i], 1e-5);
        EXPECT_EQ(rg.surface[i], rb.surface[i]);
        ++kinds[rg.surface[i]];
    }
    EXPECT_GT(kinds[kGround], 100);
    EXPECT_GT(kinds[kStem], 50);
    EXPECT_GT(kinds[kFoliage], 50);
}
