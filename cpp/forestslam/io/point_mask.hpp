#pragma once
// Which points of a packed point buffer (a PointCloud2's data) are real returns.
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace forestslam::io {

/// Layout of the x, y, z fields in a PointCloud2-style buffer: `height` rows of `row_step`
/// bytes, each holding `width` points of `point_step` bytes; x, y, z at `offsets`, all float32
/// (`scalar_bytes` 4) or all float64 (8), in big- or little-endian byte order.
struct XyzLayout {
    std::size_t height = 1, width = 0, point_step = 0, row_step = 0;
    std::array<std::size_t, 3> offsets{0, 4, 8};
    int scalar_bytes = 4;
    bool big_endian = false;
};

/// Row-major indices (row * width + column) of the points whose x, y, z are all finite and not
/// all zero (drivers mark "no return" with NaN or with the origin). Throws std::invalid_argument
/// when the layout does not fit in `size` bytes or the fields overrun `point_step`.
std::vector<std::int64_t> realPointIndices(const std::uint8_t *data, std::size_t size,
                                           const XyzLayout &layout);

}  // namespace forestslam::io
