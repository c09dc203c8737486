#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <stdexcept>

#include "forestslam/localization/feature_index.hpp"

TEST(FeatureIndex, KnnMatchesBruteForce) {
    std::mt19937 rng(3);
    std::normal_distribution<double> g(0, 1);
    forestslam::localization::KdTree::Matrix pts(2000, 8);
    for (Eigen::Index i = 0; i < pts.rows(); ++i)
        for (int d = 0; d < 8; ++d) pts(i, d) = g(rng);
    const forestslam::localization::KdTree tree(pts);
    std::vector<int> idx;
    std::vector<double> dist;
    for (int q = 0; q < 50; ++q) {
        Eigen::VectorXd query(8);
        for (int d = 0; d < 8; ++d) query[d] = g(rng);
        tree.knn(query, 5, 1e9, idx, dist);
        std::vector<std::pair<double, int>> all;
        for (Eigen::Index i = 0; i < pts.rows(); ++i)
            all.push_back({(pts.row(i).transpose() - query).norm(), int(i)});
        std::sort(all.begin(), all.end());
        ASSERT_EQ(idx.size(), 5u);
        for (int k = 0; k < 5; ++k) {
            EXPECT_EQ(idx[k], all[k].second);
            EXPECT_NEAR(dist[k], all[k].first, 1e-12);
        }
        // A distance bound keeps only the rows within it.
        tree.knn(query, 5, all[1].first + 1e-12, idx, dist);
        EXPECT_EQ(idx.size(), 2u);
    }
}

TEST(FeatureIndex, GridNearestWithinGate) {
    forestslam::Points2 xy(4, 2);
    xy << 0, 0, 10, 10, 10.3, 10, -5, 3;
    const forestslam::localization::PointGrid grid(xy, 1.0);
    double d2 = 0;
    EXPECT_EQ(grid.nearest(10.2, 10.0, 0.5, &d2), 2);
    EXPECT_NEAR(d2, 0.01, 1e-12);
    EXPECT_EQ(grid.nearest(-4.6, 3.0, 0.5), 3);
    EXPECT_EQ(grid.nearest(-4.4, 3.0, 0.5), -1);
    EXPECT_EQ(grid.nearest(0.0, 2.5, 3.0), 0);  // gate wider than a cell
    EXPECT_EQ(grid.nearest(NAN, 0.0, 1.0), -1);
}

TEST(FeatureIndex, QueryOfAnotherDimensionThrows) {
    const forestslam::localization::KdTree tree(
        forestslam::localization::KdTree::Matrix::Zero(5, 8));
    std::vector<int> idx;
    std::vector<double> dist;
    EXPECT_THROW(tree.knn(Eigen::VectorXd::Zero(7), 3, 1.0, idx, dist), std::invalid_argument);
}
