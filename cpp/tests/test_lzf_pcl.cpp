// Our LZF against PCL's (pcl/io/lzf.h): each side decodes what the other encodes, so PCD files
// written by PCL with DATA binary_compressed read back, and ours read in PCL.
#include <gtest/gtest.h>
#include <pcl/io/lzf.h>

#include <cmath>
#include <random>
#include <vector>

#include "forestslam/io/lzf.hpp"

using Bytes = std::vector<std::uint8_t>;

namespace {
Bytes pointCloudLikeBytes(std::size_t n_points) {
    // Field after field, as binary_compressed PCD stores them: x, y, z float32, ring uint16.
    std::mt19937 rng(3);
    std::normal_distribution<float> noise(0.f, 0.01f);
    std::vector<float> xyz(3 * n_points);
    for (std::size_t i = 0; i < n_points; ++i) {
        const float a = 0.0035f * static_cast<float>(i);
        xyz[i] = 10.f * std::cos(a) + noise(rng);
        xyz[n_points + i] = 10.f * std::sin(a) + noise(rng);
        xyz[2 * n_points + i] = -1.5f;
    }
    Bytes out(reinterpret_cast<const std::uint8_t *>(xyz.data()),
              reinterpret_cast<const std::uint8_t *>(xyz.data() + xyz.size()));
    for (std::size_t i = 0; i < n_points; ++i) {
        const std::uint16_t ring = static_cast<std::uint16_t>(i % 16);
        out.push_back(static_cast<std::uint8_t>(ring & 0xff));
        out.push_back(static_cast<std::uint8_t>(ring >> 8));
    }
    return out;
}
}  // namespace

TEST(LzfPcl, PclCompressedDecodesWithOurs) {
    const Bytes data = pointCloudLikeBytes(20000);
    Bytes packed(data.size() * 2 + 64);
    const unsigned size = pcl::lzfCompress(data.data(), static_cast<unsigned>(data.size()),
                                           packed.data(), static_cast<unsigned>(packed.size()));
    ASSERT_GT(size, 0u);
    EXPECT_EQ(forestslam::io::lzfDecompress(packed.data(), size, data.size()), data);
}

TEST(LzfPcl, OursDecodesWithPcl) {
    const Bytes data = pointCloudLikeBytes(20000);
    const Bytes packed = forestslam::io::lzfCompress(data.data(), data.size());
    EXPECT_LT(packed.size(), data.size());  // the constant z and ring columns compress
    Bytes out(data.size());
    const unsigned size = pcl::lzfDecompress(packed.data(), static_cast<unsigned>(packed.size()),
                                             out.data(), static_cast<unsigned>(out.size()));
    ASSERT_EQ(size, data.size());
    EXPECT_EQ(out, data);
}
