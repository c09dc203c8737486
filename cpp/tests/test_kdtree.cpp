#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <random>
#include <vector>

#include "forestslam/common/kdtree.hpp"

namespace fs = forestslam;

namespace {
fs::Points3 randomCloud(int n, std::mt19937 &rng) {
    std::uniform_real_distribution<double> u(-10.0, 10.0);
    fs::Points3 p(n, 3);
    for (int i = 0; i < n; ++i) p.row(i) << u(rng), u(rng), 0.2 * u(rng);
    return p;
}

// Squared distances from q to the given rows, ascending.
std::vector<std::pair<double, int>> bruteForce(const fs::Points3 &p, const std::vector<int> &rows,
                                               const Eigen::Vector3d &q) {
    std::vector<std::pair<double, int>> d;
    for (int r : rows) d.emplace_back((p.row(r).transpose() - q).squaredNorm(), r);
    std::sort(d.begin(), d.end());
    return d;
}
}  // namespace

TEST(KdTree3, NearestAndKnnMatchBruteForceOnASubsetOfRows) {
    std::mt19937 rng(7);
    const fs::Points3 p = randomCloud(3000, rng);
    std::vector<int> rows;
    for (int i = 0; i < 3000; i += 3) rows.push_back(i);  // the tree sees every third row only
    fs::KdTree3 tree;
    tree.build(p, rows);
    ASSERT_FALSE(tree.empty());
    std::uniform_real_distribution<double> u(-11.0, 11.0);
    std::vector<std::pair<double, int>> out;
    for (int t = 0; t < 200; ++t) {
        const Eigen::Vector3d q(u(rng), u(rng), 0.2 * u(rng));
        const auto truth = bruteForce(p, rows, q);
        double d2 = -1;
        EXPECT_EQ(tree.nearest(q, 1e9, d2), truth[0].second);
        EXPECT_DOUBLE_EQ(d2, truth[0].first);
        // A finite bound (candidates buffered) and none (a heap) give the same answer.
        for (const double bound : {1e9, std::numeric_limits<double>::infinity()}) {
            ASSERT_EQ(tree.knn(q, 8, bound, out), 8);
            std::sort(out.begin(), out.end());
            for (int k = 0; k < 8; ++k) EXPECT_EQ(out[k].second, truth[k].second);
        }
    }
}

TEST(KdTree3, MaximumDistanceBoundsTheAnswer) {
    std::mt19937 rng(11);
    const fs::Points3 p = randomCloud(500, rng);
    std::vector<int> rows(500);
    for (int i = 0; i < 500; ++i) rows[i] = i;
    fs::KdTree3 tree;
    tree.build(p, rows);
    const Eigen::Vector3d far(100.0, 100.0, 0.0);
    double d2 = 0;
    EXPECT_EQ(tree.nearest(far, 1.0, d2), -1);
    std::vector<std::pair<double, int>> out;
    EXPECT_EQ(tree.knn(far, 5, 1.0, out), 0);
    // Within a radius: exactly the points brute force finds, even when fewer than k.
    const Eigen::Vector3d q = p.row(17).transpose();
    const auto truth = bruteForce(p, rows, q);
    const double r2 = 4.0;  // about ten points
    const auto inside =
        std::count_if(truth.begin(), truth.end(), [&](const auto &d) { return d.first <= r2; });
    ASSERT_GT(inside, 3);
    EXPECT_EQ(tree.knn(q, 400, r2, out), static_cast<int>(inside));
}

TEST(KdTree3, EmptyTreeAnswersNothing) {
    fs::KdTree3 tree;
    tree.build(fs::Points3(0, 3), {});
    EXPECT_TRUE(tree.empty());
    double d2 = 0;
    EXPECT_EQ(tree.nearest(Eigen::Vector3d::Zero(), 1.0, d2), -1);
    std::vector<std::pair<double, int>> out;
    EXPECT_EQ(tree.knn(Eigen::Vector3d::Zero(), 3, 1.0, out), 0);
}

// On a lattice many points lie on split planes and at equal distances (ties), where the pruning
// by cell distance is at its edge: a radius search still returns every point brute force finds
// within the radius, boundary included, and the nearest is at the true nearest distance.
TEST(KdTree3, LatticeTiesAndBoundaryPointsAreNotPruned) {
    fs::Points3 p(7 * 7 * 5, 3);
    int n = 0;
    for (int x = 0; x < 7; ++x)
        for (int y = 0; y < 7; ++y)
            for (int z = 0; z < 5; ++z) p.row(n++) << 0.5 * x, 0.5 * y, 0.5 * z;
    std::vector<int> rows(static_cast<size_t>(n));
    for (int i = 0; i < n; ++i) rows[static_cast<size_t>(i)] = i;
    fs::KdTree3 tree;
    tree.build(p, rows);
    std::vector<std::pair<double, int>> out;
    for (const Eigen::Vector3d q :
         {Eigen::Vector3d(1.5, 1.5, 1.0), Eigen::Vector3d(1.25, 1.0, 0.75),
          Eigen::Vector3d(0.0, 3.0, 2.0)}) {
        const auto truth = bruteForce(p, rows, q);
        for (const double r2 : {0.25, 0.5, 0.75, 1.0}) {
            const auto inside = std::count_if(truth.begin(), truth.end(),
                                              [&](const auto &d) { return d.first <= r2; });
            EXPECT_EQ(tree.knn(q, n, r2, out), static_cast<int>(inside));
        }
        double d2 = -1;
        ASSERT_GE(tree.nearest(q, 1e9, d2), 0);
        EXPECT_DOUBLE_EQ(d2, truth[0].first);
    }
}
