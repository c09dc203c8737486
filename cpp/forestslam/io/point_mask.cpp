#include "forestslam/io/point_mask.hpp"

#include <cmath>
#include <cstring>
#include <stdexcept>

namespace forestslam::io {

namespace {
template <typename Scalar>
Scalar load(const std::uint8_t *p, bool swap) {
    std::uint8_t bytes[sizeof(Scalar)];
    std::memcpy(bytes, p, sizeof(Scalar));  // unaligned and possibly byte-swapped
    if (swap) {
        for (std::size_t i = 0; i < sizeof(Scalar) / 2; ++i)
            std::swap(bytes[i], bytes[sizeof(Scalar) - 1 - i]);
    }
    Scalar value;
    std::memcpy(&value, bytes, sizeof(Scalar));
    return value;
}

template <typename Scalar>
void collect(const std::uint8_t *data, const XyzLayout &l, bool swap,
             std::vector<std::int64_t> &out) {
    for (std::size_t r = 0; r < l.height; ++r) {
        const std::uint8_t *row = data + r * l.row_step;
        for (std::size_t c = 0; c < l.width; ++c) {
            const std::uint8_t *p = row + c * l.point_step;
            const Scalar x = load<Scalar>(p + l.offsets[0], swap);
            const Scalar y = load<Scalar>(p + l.offsets[1], swap);
            const Scalar z = load<Scalar>(p + l.offsets[2], swap);
            if (std::isfinite(x) && std::isfinite(y) && std::isfinite(z) &&
                (x != 0 || y != 0 || z != 0))
                out.push_back(static_cast<std::int64_t>(r * l.width + c));
        }
    }
}

bool hostIsBigEndian() {
    const std::uint16_t probe = 1;
    std::uint8_t first;
    std::memcpy(&first, &probe, 1);
    return first == 0;
}
}  // namespace

std::vector<std::int64_t> realPointIndices(const std::uint8_t *data, std::size_t size,
                                           const XyzLayout &l) {
    if (l.scalar_bytes != 4 && l.scalar_bytes != 8)
        throw std::invalid_argument("x, y, z must be float32 or float64");
    for (std::size_t offset : l.offsets) {
        if (offset + static_cast<std::size_t>(l.scalar_bytes) > l.point_step)
            throw std::invalid_argument("a coordinate field overruns point_step");
    }
    std::vector<std::int64_t> out;
    if (l.height == 0 || l.width == 0) return out;
    if (l.row_step < l.width * l.point_step)
        throw std::invalid_argument("row_step smaller than width * point_step");
    if ((l.height - 1) * l.row_step + l.width * l.point_step > size)
        throw std::invalid_argument("point data shorter than its layout");
    out.reserve(l.height * l.width);
    const bool swap = l.big_endian != hostIsBigEndian();
    if (l.scalar_bytes == 4)
        collect<float>(data, l, swap, out);
    else
        collect<double>(data, l, swap, out);
    return out;
}

}  // namespace forestslam::io
