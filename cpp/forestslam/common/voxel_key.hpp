// Exact integer keys of grid cells and voxels for hash maps. A key packs the cell indices (21
// bits per axis in 3D, 32 in 2D), so two cells share a key only when their indices differ by a
// multiple of 2^21 (2^32): 2,097,152 cells, over 100 km at 5 cm. An XOR of scaled indices, used
// as the key itself, would merge unrelated cells silently.
#pragma once

#include <cmath>
#include <cstdint>

namespace forestslam {

inline std::int64_t cellIndex(double value, double cell) {
    return static_cast<std::int64_t>(std::floor(value / cell));
}

inline std::uint64_t cellKey2(std::int64_t ix, std::int64_t iy) {
    return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(ix)) << 32) |
           static_cast<std::uint32_t>(iy);
}

inline std::uint64_t cellKey3(std::int64_t ix, std::int64_t iy, std::int64_t iz) {
    constexpr std::uint64_t kMask = 0x1FFFFF;
    return ((static_cast<std::uint64_t>(ix) & kMask) << 42) |
           ((static_cast<std::uint64_t>(iy) & kMask) << 21) |
           (static_cast<std::uint64_t>(iz) & kMask);
}

inline std::uint64_t voxelKey(double x, double y, double z, double voxel) {
    return cellKey3(cellIndex(x, voxel), cellIndex(y, voxel), cellIndex(z, voxel));
}

}  // namespace forestslam
