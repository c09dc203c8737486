#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <vector>

#include "forestslam/io/point_mask.hpp"

using forestslam::io::realPointIndices;
using forestslam::io::XyzLayout;

namespace {
template <typename Scalar>
void put(std::vector<std::uint8_t> &buf, std::size_t at, Scalar v, bool big_endian) {
    std::uint8_t bytes[sizeof(Scalar)];
    std::memcpy(bytes, &v, sizeof(Scalar));
    for (std::size_t i = 0; i < sizeof(Scalar); ++i)
        buf[at + i] = big_endian ? bytes[sizeof(Scalar) - 1 - i] : bytes[i];
}
}  // namespace

TEST(PointMask, PackedVelodyneLayoutDropsNanInfAndOrigin) {
    XyzLayout l;  // x, y, z float32 at 0, 4, 8 in 22-byte points (the Velodyne driver layout)
    l.width = 6;
    l.point_step = 22;
    l.row_step = 22 * 6;
    std::vector<std::uint8_t> buf(l.row_step, 0xAB);
    const float nan = std::numeric_limits<float>::quiet_NaN();
    const float inf = std::numeric_limits<float>::infinity();
    const float xs[6] = {1.f, nan, 0.f, 2.f, 0.f, 3.f};
    const float ys[6] = {1.f, 1.f, 0.f, inf, 0.f, 0.f};
    const float zs[6] = {1.f, 1.f, 0.f, 1.f, -0.5f, 0.f};
    for (std::size_t i = 0; i < 6; ++i) {
        put(buf, i * 22 + 0, xs[i], false);
        put(buf, i * 22 + 4, ys[i], false);
        put(buf, i * 22 + 8, zs[i], false);
    }
    EXPECT_EQ(realPointIndices(buf.data(), buf.size(), l), (std::vector<std::int64_t>{0, 4, 5}));
}

TEST(PointMask, OrganizedBigEndianFloat64WithRowPadding) {
    XyzLayout l;
    l.height = 3;
    l.width = 2;
    l.point_step = 32;
    l.row_step = 2 * 32 + 8;  // padded rows
    l.offsets = {16, 0, 8};   // z, y, x order in memory: x at 16
    l.scalar_bytes = 8;
    l.big_endian = true;
    std::vector<std::uint8_t> buf(3 * l.row_step, 0);
    for (std::size_t r = 0; r < 3; ++r) {
        for (std::size_t c = 0; c < 2; ++c) {
            const std::size_t at = r * l.row_step + c * l.point_step;
            const double x = (r == 1 && c == 0) ? std::nan("") : 1.0 + r;
            put(buf, at + 16, x, true);
            put(buf, at + 0, 2.0, true);
            put(buf, at + 8, -1.0, true);
        }
    }
    EXPECT_EQ(realPointIndices(buf.data(), buf.size(), l),
              (std::vector<std::int64_t>{0, 1, 3, 4, 5}));
}

TEST(PointMask, RejectsLayoutsThatDoNotFit) {
    XyzLayout l;
    l.width = 10;
    l.point_step = 12;
    l.row_step = 120;
    std::vector<std::uint8_t> buf(100);
    EXPECT_THROW(realPointIndices(buf.data(), buf.size(), l), std::invalid_argument);
    l.offsets = {0, 4, 10};
    buf.resize(120);
    EXPECT_THROW(realPointIndices(buf.data(), buf.size(), l), std::invalid_argument);
    l.offsets = {0, 4, 8};
    l.scalar_bytes = 2;
    EXPECT_THROW(realPointIndices(buf.data(), buf.size(), l), std::invalid_argument);
    l.scalar_bytes = 4;
    l.width = 0;
    EXPECT_TRUE(realPointIndices(buf.data(), buf.size(), l).empty());
}
