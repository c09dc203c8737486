#include <gtest/gtest.h>

#include <Eigen/Geometry>
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

namespace {
// 120 leaning stems with rough bark, each with a branch and a crown; lying logs and shrubs.
struct MixedStand {
    std::vector<Stem> stems;
    std::vector<Cylinder> cylinders;
    std::vector<FoliageEllipsoid> foliage;
};

MixedStand mixedStand(std::mt19937 &rng) {
    std::uniform_real_distribution<double> u(-25, 25), r(0.05, 0.4), h(4, 25), s(-0.08, 0.08);
    std::uniform_real_distribution<double> unit(0, 1);
    MixedStand stand;
    for (int i = 0; i < 120; ++i) {
        Stem st;
        st.base = {u(rng), u(rng), 0.0};
        st.shear = {s(rng), s(rng)};
        st.semi_a = r(rng);
        st.semi_b = st.semi_a * (0.8 + 0.2 * unit(rng));
        st.angle = u(rng);
        st.taper = 0.02;
        st.height = h(rng);
        st.bark_amp = 0.004;
        for (double &ph : st.phase) ph = 6.28 * unit(rng);
        stand.stems.push_back(st);
        stand.cylinders.push_back({st.base + Eigen::Vector3d(0, 0, 2 + 3 * unit(rng)),
                                   st.base + Eigen::Vector3d(u(rng) / 10, u(rng) / 10, 4), 0.03,
                                   kBranch});
        if (i % 4 == 0)  // lying logs
            stand.cylinders.push_back({Eigen::Vector3d(u(rng), u(rng), 0.1),
                                       Eigen::Vector3d(u(rng), u(rng), 0.15), 0.15, kLog});
        stand.foliage.push_back({st.base + Eigen::Vector3d(0, 0, st.height),
                                 {1 + 2 * unit(rng), 1 + 2 * unit(rng), 2 + 2 * unit(rng)},
                                 0.5 + unit(rng),
                                 kFoliage});
        if (i % 3 == 0)
            stand.foliage.push_back(
                {Eigen::Vector3d(u(rng), u(rng), 0.4), {0.8, 0.6, 0.5}, 2.0, kShrub});
    }
    return stand;
}

// A gentle slope, every vertex jittered by up to 5 cm.
Heightfield roughTerrain(std::mt19937 &rng) {
    std::uniform_real_distribution<double> unit(0, 1);
    Eigen::MatrixXd z = planeGrid(140, 0.5, -35, -35, 0.03, -0.02, 0.0);
    for (Eigen::Index i = 0; i < z.size(); ++i) z.data()[i] += 0.05 * unit(rng);
    return Heightfield(-35, -35, 0.5, z);
}

// The rays of a tilted sensor at `origin`: spinning columns from a moving sensor, raster rows
// (horizontal fans), then steep and axis-parallel rays mixed into the same origin's run.
std::vector<Ray> sensorRays(const Eigen::Vector3d &origin, std::mt19937 &rng) {
    std::uniform_real_distribution<double> u(-25, 25), unit(0, 1);
    const double roll = 0.2 * (unit(rng) - 0.5), pitch = 0.2 * (unit(rng) - 0.5);
    const Eigen::Matrix3d rot = (Eigen::AngleAxisd(u(rng), Eigen::Vector3d::UnitZ()) *
                                 Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                                 Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
                                    .toRotationMatrix();
    std::vector<Ray> rays;
    Eigen::Vector3d o = origin;
    auto add = [&](const Eigen::Vector3d &local, uint64_t key) {
        Ray ray = makeRay(o, rot * local);
        ray.t_max = 100.0;
        ray.key = key;
        rays.push_back(ray);
    };
    // Spinning columns: 16 beams from -15 to +15 degrees, 0.4 degree steps. Each firing column
    // a little further, jittered (bundles take origins up to 1 cm apart; real columns are well
    // under a millimetre apart).
    const Eigen::Vector3d drift(2e-3, -1e-3, 5e-4);
    for (int c = 0; c < 900; ++c) {
        o += drift + 2e-3 * Eigen::Vector3d(unit(rng) - 0.5, unit(rng) - 0.5, 0.0);
        const double az = c * 2 * M_PI / 900;
        for (int b = 0; b < 16; ++b) {
            const double e = (-15.0 + 2.0 * ((b * 9) % 16)) * M_PI / 180;
            add({std::cos(e) * std::cos(az), std::cos(e) * std::sin(az), std::sin(e)}, rays.size());
        }
    }
    // Raster rows: 31 rays across 6 degrees of azimuth at one elevation.
    o = origin;
    for (int g = 0; g < 60; ++g) {
        const double az0 = 2 * M_PI * unit(rng), e = 0.4 * (unit(rng) - 0.6);
        for (int k = 0; k < 31; ++k) {
            const double az = az0 + k * 0.0035;
            add({std::cos(e) * std::cos(az), std::cos(e) * std::sin(az), std::sin(e)}, rays.size());
        }
    }
    for (double e : {1.55, -1.55, 1.2, -1.2}) add({std::cos(e), 0, std::sin(e)}, 7);
    for (const Eigen::Vector3d &d :
         {Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, -1, 0), Eigen::Vector3d(0, 1, 0),
          Eigen::Vector3d(-1, 0, -0.05), Eigen::Vector3d(0, 0, -1)})
        add(rot.transpose() * d, 11);
    return rays;
}

// castBatch must give exactly cast()'s hit for every ray; counts the rays per surface.
void expectBatchEqualsCast(const ForestScene &scene, const std::vector<Ray> &rays,
                           int (&kinds)[7]) {
    std::vector<Hit> hits(rays.size());
    scene.castBatch(rays.data(), rays.size(), hits.data());
    for (size_t i = 0; i < rays.size(); ++i) {
        const Hit one = scene.cast(rays[i]);
        ASSERT_EQ(hits[i].t, one.t) << i;
        ASSERT_EQ(hits[i].surface, one.surface) << i;
        ASSERT_EQ(hits[i].object, one.object) << i;
        ASSERT_EQ(hits[i].cos_incidence, one.cos_incidence) << i;
        ++kinds[one.surface];
    }
}
}  // namespace

TEST(ForestScene, BundledCastsMatchRayByRayCasts) {
    // castBatch walks the grid once per bundle of rays sharing an origin; it must return
    // exactly cast()'s hit for every ray: tilted spinning columns, raster rows (horizontal
    // fans), steep rays, sensors outside the grid, axis-parallel rays.
    std::mt19937 rng(23);
    const MixedStand stand = mixedStand(rng);
    const Heightfield hf = roughTerrain(rng);
    int kinds[7] = {0};
    for (double cell_m : {3.0, 1.3}) {
        const ForestScene scene(hf, stand.stems, stand.cylinders, stand.foliage, cell_m);
        for (const Eigen::Vector3d origin :
             {Eigen::Vector3d(0.3, -0.7, 1.2), Eigen::Vector3d(14.0, 9.0, 2.5),
              Eigen::Vector3d(-60.0, 3.0, 1.0), Eigen::Vector3d(40.0, 45.0, 12.0)})
            expectBatchEqualsCast(scene, sensorRays(origin, rng), kinds);
    }
    int checked = 0;
    for (int k : kinds) checked += k;
    EXPECT_GT(checked, 100000);
    EXPECT_GT(kinds[kGround], 5000);
    EXPECT_GT(kinds[kStem], 2000);
    EXPECT_GT(kinds[kFoliage], 2000);
    EXPECT_GT(kinds[kBranch], 20);
    EXPECT_GT(kinds[kLog], 20);
    EXPECT_GT(kinds[kShrub], 20);
}

TEST(ForestScene, BundleWithNearbyOriginsKeepsHitsOfTheOffsetRays) {
    // Parallel rays from origins spread over 9.5 mm across a thin vertical branch 10 m away: the
    // first origin's ray misses it, the others hit or miss it depending on their own origin. A
    // bundle must not judge the others by the first origin.
    const Cylinder branch{{10, 0, 0}, {10, 0, 3}, 0.02, kBranch};
    const ForestScene scene(Heightfield(), {}, {branch}, {}, 3.0);
    std::vector<Ray> rays;
    for (int k = 0; k < 64; ++k) {
        Ray ray = makeRay({0, -0.025 + 0.00015 * k, 1.0}, {1, 0, 0.001 * (k % 3)});
        ray.t_max = 50;
        rays.push_back(ray);
    }
    std::vector<Hit> hits(rays.size());
    scene.castBatch(rays.data(), rays.size(), hits.data());
    int n_hit = 0;
    for (size_t i = 0; i < rays.size(); ++i) {
        const Hit one = scene.cast(rays[i]);
        EXPECT_EQ(hits[i].t, one.t) << i;
        EXPECT_EQ(hits[i].object, one.object) << i;
        n_hit += one.valid();
    }
    EXPECT_GT(n_hit, 20);
    EXPECT_LT(n_hit, 64);
}

TEST(ForestScene, BundleWalkStartsBehindTheFirstOrigin) {
    // The first ray's origin lies just past a cell boundary; the second ray starts 4.5 mm
    // behind it, in the previous cell, and meets a thin twig there at once.
    // The anchors make the grid start at x = 0 and span three 3 m cells.
    const Cylinder anchor{{0.05, 10, 0}, {0.05, 10, 3}, 0.05, kBranch};
    const Cylinder far_anchor{{8.5, 10, 0}, {8.5, 10, 3}, 0.05, kBranch};
    const Cylinder twig{{2.998, 0, 0}, {2.998, 0, 2}, 0.0005, kBranch};
    const ForestScene scene(Heightfield(), {}, {anchor, twig, far_anchor}, {}, 3.0);
    std::vector<Ray> rays = {makeRay({3.0005, 0, 1}, {1, 0, 0}), makeRay({2.996, 0, 1}, {1, 0, 0})};
    std::vector<Hit> hits(rays.size());
    scene.castBatch(rays.data(), rays.size(), hits.data());
    EXPECT_FALSE(scene.cast(rays[0]).valid());
    EXPECT_FALSE(hits[0].valid());
    const Hit one = scene.cast(rays[1]);
    ASSERT_TRUE(one.valid());
    EXPECT_NEAR(one.t, 0.0015, 1e-9);
    EXPECT_EQ(hits[1].t, one.t);
    EXPECT_EQ(hits[1].object, 1);
}

TEST(ForestScene, BundledCastsMatchAmongDenseTwigsNearTheSensors) {
    // Stress for the bundle's conservative rejections: many millimetre twigs and small leaf
    // clumps right around the sensors, small cells (frequent boundaries), origins jittered by up
    // to 1 cm within a bundle, fans up to the bundling limit, every walk direction.
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> unit(0, 1), pos(-4, 4);
    std::vector<Cylinder> cyl;
    std::vector<FoliageEllipsoid> fol;
    std::vector<Stem> stems;
    for (int i = 0; i < 1500; ++i) {
        const Eigen::Vector3d a(pos(rng), pos(rng), 2 * unit(rng));
        const Eigen::Vector3d d = Eigen::Vector3d(pos(rng), pos(rng), pos(rng)).normalized();
        cyl.push_back({a, a + (0.05 + 0.3 * unit(rng)) * d, 0.001 + 0.004 * unit(rng), kBranch});
    }
    for (int i = 0; i < 300; ++i)
        fol.push_back({{pos(rng), pos(rng), 2 * unit(rng)},
                       {0.02 + 0.1 * unit(rng), 0.02 + 0.1 * unit(rng), 0.02 + 0.1 * unit(rng)},
                       5.0,
                       kShrub});
    for (int i = 0; i < 20; ++i) {
        Stem st;
        st.base = {pos(rng), pos(rng), 0.0};
        st.semi_a = st.semi_b = 0.03 + 0.05 * unit(rng);
        st.height = 2.5;
        st.bark_amp = 0.002;
        stems.push_back(st);
    }
    const Heightfield hf(-6, -6, 0.5, planeGrid(24, 0.5, -6, -6, 0.02, 0.01, -0.2));
    int checked = 0, hit_objects = 0;
    for (double cell_m : {0.7, 0.31}) {
        const ForestScene scene(hf, stems, cyl, fol, cell_m);
        std::vector<Ray> rays;
        for (int b = 0; b < 400; ++b) {
            const Eigen::Vector3d o(pos(rng), pos(rng), 0.2 + 1.6 * unit(rng));
            const double az = 2 * M_PI * unit(rng), fan = 0.2 * unit(rng);
            const int m = 2 + static_cast<int>(60 * unit(rng));
            for (int k = 0; k < m; ++k) {
                const double a = az + fan * unit(rng), e = 0.8 * (unit(rng) - 0.5);
                Ray ray =
                    makeRay(o + 0.01 * Eigen::Vector3d(unit(rng), unit(rng), unit(rng)),
                            {std::cos(e) * std::cos(a), std::cos(e) * std::sin(a), std::sin(e)});
                ray.t_max = 20.0;
                ray.key = rays.size();
                rays.push_back(ray);
            }
        }
        std::vector<Hit> hits(rays.size());
        scene.castBatch(rays.data(), rays.size(), hits.data());
        for (size_t i = 0; i < rays.size(); ++i) {
            const Hit one = scene.cast(rays[i]);
            ASSERT_EQ(hits[i].t, one.t) << i;
            ASSERT_EQ(hits[i].object, one.object) << i;
            ASSERT_EQ(hits[i].surface, one.surface) << i;
            hit_objects += one.valid() && one.surface != kGround;
            ++checked;
        }
    }
    EXPECT_GT(checked, 20000);
    EXPECT_GT(hit_objects, 2000);
}

TEST(ForestScene, BundleKeepsAnOffsetRayUpToItsOwnRangeEnd) {
    // The second ray starts 5 mm ahead of the first; its range ends 4.5 mm past a cell
    // boundary, just after a twig that lies wholly in the next cell. Seen from the first origin
    // its range ends before the boundary: the bundle must still test the twig for it.
    const Cylinder anchor{{0.05, 10, 0}, {0.05, 10, 3}, 0.05, kBranch};  // grid from x = 0
    const Cylinder far_anchor{{8.5, 10, 0}, {8.5, 10, 3}, 0.05, kBranch};
    const Cylinder twig{{3.002, 0, 0}, {3.002, 0, 2}, 0.0005, kBranch};
    const ForestScene scene(Heightfield(), {}, {anchor, twig, far_anchor}, {}, 3.0);
    std::vector<Ray> rays = {makeRay({0.5, 0.008, 1}, {1, 0, 0}),
                             makeRay({0.505, 0, 1}, {1, 0, 0})};
    rays[1].t_max = 2.4995;
    std::vector<Hit> hits(rays.size());
    scene.castBatch(rays.data(), rays.size(), hits.data());
    const Hit one = scene.cast(rays[1]);
    ASSERT_TRUE(one.valid());
    EXPECT_NEAR(one.t, 2.4965, 1e-9);
    EXPECT_EQ(hits[1].t, one.t);
    EXPECT_EQ(hits[1].object, 1);
    EXPECT_EQ(hits[0].t, scene.cast(rays[0]).t);
}
