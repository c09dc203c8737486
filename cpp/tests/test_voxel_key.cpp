#include <gtest/gtest.h>

#include <unordered_set>

#include "forestslam/common/voxel_key.hpp"

namespace fs = forestslam;

TEST(VoxelKey, EveryCellOfABlockAroundTheOriginHasItsOwnKey) {
    std::unordered_set<std::uint64_t> keys3, keys2;
    int cells = 0;
    for (int x = -40; x < 40; ++x)
        for (int y = -40; y < 40; ++y) {
            keys2.insert(fs::cellKey2(x, y));
            for (int z = -10; z < 10; ++z, ++cells) keys3.insert(fs::cellKey3(x, y, z));
        }
    EXPECT_EQ(keys3.size(), static_cast<size_t>(cells));
    EXPECT_EQ(keys2.size(), 80u * 80u);
}

TEST(VoxelKey, PointsShareAKeyExactlyWhenTheyShareAVoxel) {
    const double v = 0.25;
    EXPECT_EQ(fs::voxelKey(0.01, 0.01, 0.01, v), fs::voxelKey(0.24, 0.24, 0.24, v));
    EXPECT_NE(fs::voxelKey(0.24, 0.0, 0.0, v), fs::voxelKey(0.26, 0.0, 0.0, v));
    EXPECT_NE(fs::voxelKey(-0.01, 0.0, 0.0, v), fs::voxelKey(0.01, 0.0, 0.0, v));  // floor
    EXPECT_NE(fs::voxelKey(0.0, 0.0, -0.01, v), fs::voxelKey(0.0, 0.0, 0.01, v));
    // Axes are not interchangeable.
    EXPECT_NE(fs::cellKey3(1, 2, 3), fs::cellKey3(3, 2, 1));
    EXPECT_NE(fs::cellKey2(1, 2), fs::cellKey2(2, 1));
    // UTM-sized indices stay distinct from their neighbours.
    EXPECT_NE(fs::voxelKey(470'000.0, 3'810'000.0, 2'000.0, v),
              fs::voxelKey(470'000.3, 3'810'000.0, 2'000.0, v));
}
