#include <gtest/gtest.h>
#include <pcl/console/print.h>
#include <pcl/segmentation/approximate_progressive_morphological_filter.h>

#include <random>

#include "forestslam/perception/morphological_ground.hpp"

using namespace forestslam::perception;

namespace {

// Lowest points of a `cell` grid over a rough slope with stems and bushes (seeded).
std::vector<Eigen::Vector3f> terrainCells(unsigned seed, float cell, int n) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<float> xy(-30.0f, 30.0f), u(0.0f, 1.0f);
    std::normal_distribution<float> noise(0.0f, 0.05f);
    std::vector<Eigen::Vector3f> cells;
    for (int k = 0; k < n; ++k) {
        const float x = std::floor(xy(rng) / cell) * cell + cell * u(rng);
        const float y = std::floor(xy(rng) / cell) * cell + cell * u(rng);
        float z = 0.15f * x - 0.05f * y + 0.5f * std::sin(0.2f * x) + noise(rng);
        if (u(rng) < 0.1f) z += 3.0f * u(rng);  // stems, bushes, branches
        cells.emplace_back(x, y, z);
    }
    return cells;
}

pcl::Indices pclGround(const std::vector<Eigen::Vector3f> &cells, float cell,
                       const GroundConfig &o) {
    pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
    for (const auto &p : cells) cloud->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
    pcl::ApproximateProgressiveMorphologicalFilter<pcl::PointXYZ> pmf;
    pmf.setInputCloud(cloud);
    pmf.setCellSize(cell);
    pmf.setMaxWindowSize(o.max_window_cells);
    pmf.setSlope(static_cast<float>(o.slope));
    pmf.setInitialDistance(static_cast<float>(o.initial_distance_m));
    pmf.setMaxDistance(static_cast<float>(o.max_distance_m));
    pmf.setBase(static_cast<float>(o.base));
    pmf.setExponential(o.exponential);
    pmf.setNumberOfThreads(1);
    pcl::Indices ground;
    pmf.extract(ground);
    return ground;
}

}  // namespace

TEST(MorphologicalGround, SameCellsAsPclsFilter) {
    pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS);
    GroundConfig wide;
    wide.max_window_cells = 17;  // windows 3, 5, 9, 17
    GroundConfig linear;
    linear.exponential = false;
    linear.max_window_cells = 9;
    linear.slope = 0.3;
    for (const GroundConfig &o : {GroundConfig{}, wide, linear}) {
        for (unsigned seed = 1; seed <= 3; ++seed) {
            for (const float cell : {0.5f, 0.3f}) {
                const auto cells = terrainCells(seed, cell, 4000);
                const std::vector<int> ours = morphologicalGround(cells, cell, o);
                const pcl::Indices theirs = pclGround(cells, cell, o);
                ASSERT_GT(ours.size(), cells.size() / 2);     // the terrain is ground
                ASSERT_LT(ours.size(), cells.size() * 0.99);  // the stems are not
                EXPECT_EQ(ours, std::vector<int>(theirs.begin(), theirs.end()));
            }
        }
    }
}

TEST(MorphologicalGround, EmptyInputHasNoGround) {
    EXPECT_TRUE(morphologicalGround({}, 0.5f, GroundConfig{}).empty());
}
