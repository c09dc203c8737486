#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <stdexcept>
#include <tuple>

#include "forestslam/perception/segmentation.hpp"
#include "perception_scene.hpp"

using namespace forestslam;
using namespace forestslam::perception;

namespace {

// Stem points only (no ground) of a cast scan.
test::SceneScan stemsOnly(const std::vector<test::Tree> &trees) {
    auto s = test::castScan(trees, 1.8, 0.005, 3);
    std::vector<int> rows;
    for (Eigen::Index i = 0; i < s.points.rows(); ++i)
        if (s.points(i, 2) > -1.5) rows.push_back(static_cast<int>(i));
    test::SceneScan out;
    out.points = selectRows(s.points, rows);
    out.ring.resize(static_cast<Eigen::Index>(rows.size()));
    for (size_t k = 0; k < rows.size(); ++k)
        out.ring(static_cast<Eigen::Index>(k)) = s.ring(rows[k]);
    return out;
}

int clusterOf(const Clusters &c, int row) {
    for (size_t k = 0; k < c.size(); ++k)
        for (int r : c[k])
            if (r == row) return static_cast<int>(k);
    return -1;
}

}  // namespace

TEST(Segmentation, ProjectionByRingAndByElevationAgree) {
    const auto s = stemsOnly({{5, 0.5, 0.3}});
    const auto g = test::vlp16Geometry();
    const auto by_ring = projectToRangeImage(s.points, s.ring, g);
    const auto by_angle = projectToRangeImage(s.points, Eigen::VectorXi(), g);
    ASSERT_GT(s.points.rows(), 50);
    for (Eigen::Index i = 0; i < s.points.rows(); ++i) {
        EXPECT_EQ(by_ring.row[i], by_angle.row[i]);
        EXPECT_EQ(by_ring.col[i], by_angle.col[i]);
        EXPECT_GE(by_ring.col[i], 0);
    }
}

TEST(Segmentation, DivideAndMergeSeparatesStemsAndJoinsAcrossBlocks) {
    // A near stem in front of a far one at nearly the same azimuth, and a wide stem whose
    // columns straddle a block edge (azimuth 0 = column 900, a multiple of 32 is 896).
    const auto s = stemsOnly({{4, 0.0, 0.3}, {9, 0.35, 0.4}, {-3, -3, 0.6}});
    const auto g = test::vlp16Geometry();
    const auto proj = projectToRangeImage(s.points, s.ring, g);
    SegmentationConfig o;
    o.block_cols = 8;  // many block edges
    const Clusters c = rangeImageClusters(s.points, proj, g, o, 3);
    std::set<int> near, far, wide;
    for (Eigen::Index i = 0; i < s.points.rows(); ++i) {
        const int k = clusterOf(c, static_cast<int>(i));
        if (k < 0) continue;
        const double x = s.points(i, 0), y = s.points(i, 1);
        if (std::hypot(x - 4, y) < 0.3)
            near.insert(k);
        else if (std::hypot(x - 9, y - 0.35) < 0.3)
            far.insert(k);
        else if (std::hypot(x + 3, y + 3) < 0.4)
            wide.insert(k);
    }
    ASSERT_EQ(near.size(), 1u);
    ASSERT_EQ(far.size(), 1u);
    ASSERT_EQ(wide.size(), 1u);  // merged across block edges by votes
    EXPECT_NE(*near.begin(), *far.begin());
}

TEST(Segmentation, DbscanSplitsBlobsAndDropsNoise) {
    Points3 p(9, 3);
    p << 0, 0, 0, 0.05, 0, 0, 0, 0.05, 0,  //
        1, 1, 1, 1.05, 1, 1, 1, 1.05, 1,   //
        1.02, 1.02, 1.0,                   //
        5, 5, 5,                           // isolated
        0.02, 0.02, 0.0;
    std::vector<int> rows{0, 1, 2, 3, 4, 5, 6, 7, 8};
    const Clusters c = dbscan(p, rows, 0.1, 2);
    ASSERT_EQ(c.size(), 2u);
    EXPECT_EQ(c[0].size() + c[1].size(), 8u);
    EXPECT_EQ(clusterOf(c, 7), -1);
    EXPECT_TRUE(dbscan(p, {}, 0.1, 2).empty());
}

TEST(Segmentation, AdaptiveEpsScalesWithRangeAndIsClamped) {
    Points3 p(2, 3);
    p << 10, 0, 0, 10, 0.1, 1;
    SegmentationConfig o;
    const double eps = adaptiveEps(p, {0, 1}, 0.0349, o);
    EXPECT_NEAR(eps, 1.25 * 0.0349 * std::hypot(10, 0.05), 1e-9);
    Points3 q(1, 3);
    q << 0.5, 0, 0;
    EXPECT_DOUBLE_EQ(adaptiveEps(q, {0}, 0.0349, o), o.dbscan_min_eps_m);
}

TEST(Segmentation, EuclideanClustersForMaps) {
    Points3 p(6, 3);
    p << 0, 0, 0, 0.1, 0, 0, 0.2, 0, 0, 3, 3, 3, 3.1, 3, 3, 3.2, 3, 3;
    EXPECT_EQ(euclideanClusters(p, 0.15, 2).size(), 2u);
    EXPECT_TRUE(euclideanClusters(Points3(0, 3), 0.15, 2).empty());
}

TEST(Segmentation, ThinnedNearStemStaysWholeWithTheMetricColumnGap) {
    // A stem 2 m away thinned to one point per 5 cm (as the normal filter leaves it): about 7
    // empty columns between its points. Bridged by max_gap_m it is one cluster per block; with
    // only max_pixel_gap it falls apart into vertical strips.
    const auto s = stemsOnly({{2.0, 0.0, 0.5}});
    std::vector<int> rows;
    std::set<std::tuple<long, long, long>> voxels;
    for (Eigen::Index i = 0; i < s.points.rows(); ++i) {
        const auto key = std::make_tuple(std::lround(std::floor(s.points(i, 0) / 0.05)),
                                         std::lround(std::floor(s.points(i, 1) / 0.05)),
                                         std::lround(std::floor(s.points(i, 2) / 0.05)));
        if (voxels.insert(key).second) rows.push_back(static_cast<int>(i));
    }
    const Points3 thin = selectRows(s.points, rows);
    Eigen::VectorXi ring(static_cast<Eigen::Index>(rows.size()));
    for (size_t k = 0; k < rows.size(); ++k) ring(static_cast<Eigen::Index>(k)) = s.ring(rows[k]);
    const auto g = test::vlp16Geometry();
    const auto proj = projectToRangeImage(thin, ring, g);
    SegmentationConfig o;
    o.block_cols = 512;  // one block: no merge votes involved
    const Clusters bridged = rangeImageClusters(thin, proj, g, o, 3);
    o.max_gap_m = 0.0;
    const Clusters strips = rangeImageClusters(thin, proj, g, o, 3);
    ASSERT_GT(thin.rows(), 30);
    EXPECT_EQ(bridged.size(), 1u);
    EXPECT_GT(strips.size(), 3u);
}

TEST(Segmentation, RingsOfAnotherLengthThrow) {
    const auto s = stemsOnly({{5, 0.5, 0.3}});
    const Eigen::VectorXi short_ring = s.ring.head(s.ring.size() - 1);
    EXPECT_THROW(projectToRangeImage(s.points, short_ring, test::vlp16Geometry()),
                 std::invalid_argument);
}
