#include "forestslam/features/voxel_grid.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace forestslam::features {

namespace {

// 21 bits per axis around the origin: +-1e6 voxels, enough for any plot at cm voxels.
std::uint64_t voxelKey(const Eigen::Vector3d &p, double inv) {
    auto axis = [inv](double v) {
        const auto i = static_cast<std::int64_t>(std::floor(v * inv)) + (1 << 20);
        return static_cast<std::uint64_t>(i) & 0x1FFFFFu;
    };
    return (axis(p.x()) << 42) | (axis(p.y()) << 21) | axis(p.z());
}

// Voxel key -> slot (index of the voxel, -1: new) by open addressing with linear probing.
class VoxelTable {
  public:
    explicit VoxelTable(std::size_t expected) { resize(expected); }

    // The slot of key, inserted as -1 when absent (valid until the next grow_if_needed).
    int &find(std::uint64_t key) {
        std::size_t h = hash(key);
        while (keys_[h] != kEmpty && keys_[h] != key) h = (h + 1) & mask_;
        if (keys_[h] == kEmpty) {
            keys_[h] = key;
            slots_[h] = -1;
        }
        return slots_[h];
    }

    // Doubles the table when `used` entries would fill more than half of it.
    void grow_if_needed(std::size_t used) {
        if (2 * used <= keys_.size()) return;
        std::vector<std::uint64_t> keys;
        std::vector<int> slots;
        keys.swap(keys_);
        slots.swap(slots_);
        resize(keys.size());
        for (std::size_t j = 0; j < keys.size(); ++j) {
            if (keys[j] != kEmpty) find(keys[j]) = slots[j];
        }
    }

  private:
    static constexpr std::uint64_t kEmpty = ~std::uint64_t{0};  // voxelKey never sets bit 63

    void resize(std::size_t expected) {
        bits_ = 4;
        while ((std::size_t{1} << bits_) < 2 * expected) ++bits_;
        mask_ = (std::size_t{1} << bits_) - 1;
        keys_.assign(mask_ + 1, kEmpty);
        slots_.assign(mask_ + 1, -1);
    }

    std::size_t hash(std::uint64_t key) const {
        return static_cast<std::size_t>((key * 0x9E3779B97F4A7C15ULL) >> (64 - bits_));
    }

    int bits_ = 4;
    std::size_t mask_ = 15;
    std::vector<std::uint64_t> keys_;
    std::vector<int> slots_;
};

}  // namespace

Points3 voxelDownsample(const Eigen::Ref<const Points3> &points, double voxel_m,
                        std::vector<int> &representative) {
    representative.clear();
    if (!(voxel_m > 0.0)) {
        Points3 out(points.rows(), 3);
        Eigen::Index n = 0;
        for (Eigen::Index i = 0; i < points.rows(); ++i) {
            if (points.row(i).allFinite()) {
                out.row(n++) = points.row(i);
                representative.push_back(static_cast<int>(i));
            }
        }
        out.conservativeResize(n, 3);
        return out;
    }
    const double inv = 1.0 / voxel_m;
    // Open addressing (linear probing) over a power-of-two table kept at most half full: flat
    // arrays instead of a node per voxel (std::unordered_map's allocations dominated). Voxels
    // keep the order in which they were first seen, and sums accumulate in input order.
    VoxelTable table(static_cast<std::size_t>(std::min<Eigen::Index>(points.rows(), 1 << 16)));
    std::vector<Eigen::Vector3d> sum;
    std::vector<int> count;
    for (Eigen::Index i = 0; i < points.rows(); ++i) {
        const Eigen::Vector3d p = points.row(i).transpose();
        if (!p.allFinite()) continue;
        int &k = table.find(voxelKey(p, inv));
        if (k < 0) {
            k = static_cast<int>(sum.size());
            sum.push_back(p);
            count.push_back(1);
            representative.push_back(static_cast<int>(i));
            table.grow_if_needed(sum.size());
        } else {
            sum[static_cast<std::size_t>(k)] += p;
            ++count[static_cast<std::size_t>(k)];
        }
    }
    Points3 out(static_cast<Eigen::Index>(sum.size()), 3);
    for (std::size_t k = 0; k < sum.size(); ++k) {
        out.row(static_cast<Eigen::Index>(k)) = (sum[k] / count[k]).transpose();
    }
    return out;
}

Points3 voxelDownsample(const Eigen::Ref<const Points3> &points, double voxel_m) {
    std::vector<int> unused;
    return voxelDownsample(points, voxel_m, unused);
}

namespace {

// Stable LSD radix sort of (key, point) pairs by `bits` low bits of the keys, 11 bits per pass.
void radixSort(std::vector<std::uint64_t> &keys, std::vector<std::int64_t> &rows, int bits) {
    constexpr int kDigit = 11;
    constexpr std::size_t kBuckets = std::size_t{1} << kDigit;
    std::vector<std::uint64_t> keys_tmp(keys.size());
    std::vector<std::int64_t> rows_tmp(rows.size());
    std::vector<std::size_t> offset(kBuckets);
    for (int shift = 0; shift < bits; shift += kDigit) {
        std::fill(offset.begin(), offset.end(), 0);
        for (const std::uint64_t k : keys) ++offset[(k >> shift) & (kBuckets - 1)];
        std::size_t sum = 0;
        for (std::size_t &o : offset) sum += std::exchange(o, sum);
        for (std::size_t j = 0; j < keys.size(); ++j) {
            const std::size_t at = offset[(keys[j] >> shift) & (kBuckets - 1)]++;
            keys_tmp[at] = keys[j];
            rows_tmp[at] = rows[j];
        }
        keys.swap(keys_tmp);
        rows.swap(rows_tmp);
    }
}

}  // namespace

VoxelGroups groupByVoxel(const Eigen::Ref<const Points3> &points, const Eigen::Vector3d &origin,
                         double voxel_m) {
    if (!(voxel_m > 0.0)) throw std::invalid_argument("groupByVoxel: voxel_m must be > 0");
    const Eigen::Index n = points.rows();
    auto cell = [&](Eigen::Index i, int a) {  // as numpy: floor((p - origin) / voxel_m)
        return std::floor((points(i, a) - origin(a)) / voxel_m);
    };
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (Eigen::Index i = 0; i < n; ++i)
        for (int a = 0; a < 3; ++a) {
            const double c = cell(i, a);
            if (!std::isfinite(c)) throw std::invalid_argument("groupByVoxel: a non-finite point");
            lo[a] = std::min(lo[a], c), hi[a] = std::max(hi[a], c);
        }
    VoxelGroups out;
    out.order.resize(n), out.inverse.resize(n);
    if (n == 0) return out;
    std::uint64_t span[3];
    int bits = 0;
    for (int a = 0; a < 3; ++a) {
        if (hi[a] - lo[a] >= 0x1p21)
            throw std::invalid_argument("groupByVoxel: the points span more than " +
                                        std::to_string(0x1p21 * voxel_m) + " m along an axis");
        span[a] = static_cast<std::uint64_t>(hi[a] - lo[a]) + 1;
        int b = 0;
        while ((std::uint64_t{1} << b) < span[a]) ++b;
        bits += b;
    }
    std::vector<std::uint64_t> keys(static_cast<std::size_t>(n));
    std::vector<std::int64_t> rows(static_cast<std::size_t>(n));
    for (Eigen::Index i = 0; i < n; ++i) {  // x, then y, then z: the packed keys' order
        const auto x = static_cast<std::uint64_t>(cell(i, 0) - lo[0]);
        const auto y = static_cast<std::uint64_t>(cell(i, 1) - lo[1]);
        const auto z = static_cast<std::uint64_t>(cell(i, 2) - lo[2]);
        keys[static_cast<std::size_t>(i)] = (x * span[1] + y) * span[2] + z;
        rows[static_cast<std::size_t>(i)] = i;
    }
    radixSort(keys, rows, bits);
    std::vector<std::int64_t> start;
    for (Eigen::Index j = 0; j < n; ++j) {
        const auto sj = static_cast<std::size_t>(j);
        if (j == 0 || keys[sj] != keys[sj - 1]) start.push_back(j);
        out.order(j) = rows[sj];
        out.inverse(rows[sj]) = static_cast<std::int64_t>(start.size()) - 1;
    }
    out.start = Eigen::Map<const Eigen::Matrix<std::int64_t, Eigen::Dynamic, 1>>(
        start.data(), static_cast<Eigen::Index>(start.size()));
    return out;
}

}  // namespace forestslam::features
