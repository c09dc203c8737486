#include "forestslam/perception/preprocess.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <unordered_map>

#include "forestslam/common/kdtree.hpp"
#include "forestslam/common/scatter.hpp"
#include "forestslam/common/voxel_key.hpp"
#include "forestslam/perception/morphological_ground.hpp"

namespace forestslam::perception {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

inline bool finiteRow(const Eigen::Ref<const Points3> &p, Eigen::Index i) {
    return std::isfinite(p(i, 0)) && std::isfinite(p(i, 1)) && std::isfinite(p(i, 2));
}

// Insert-only map of 3D voxel keys to ints, open addressing with linear probing: no allocation
// per key (std::unordered_* node allocations were a visible share of the ground and normals).
class VoxelIndex {
  public:
    explicit VoxelIndex(size_t expected) {
        size_t capacity = 16;
        while (capacity < 2 * expected) capacity *= 2;
        keys_.assign(capacity, kEmpty);
        values_.resize(capacity);
        mask_ = capacity - 1;
    }
    // The value of `key`, `value` inserted first when the key is new (then `inserted`).
    int &emplace(std::uint64_t key, int value, bool &inserted) {
        for (size_t i = mix(key) & mask_;; i = (i + 1) & mask_) {
            inserted = keys_[i] == kEmpty;
            if (inserted) keys_[i] = key, values_[i] = value;
            if (keys_[i] == key) return values_[i];
        }
    }

  private:
    static constexpr std::uint64_t kEmpty = ~std::uint64_t{0};  // cellKey3 uses 63 bits
    static size_t mix(std::uint64_t x) {                        // splitmix64 finaliser
        x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
        x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
        return static_cast<size_t>(x ^ (x >> 31));
    }
    std::vector<std::uint64_t> keys_;
    std::vector<int> values_;
    size_t mask_ = 0;
};

}  // namespace

std::vector<int> intensityFilter(const Eigen::Ref<const Eigen::VectorXd> &intensity,
                                 double threshold, Eigen::Index rows) {
    requirePerPoint("intensityFilter", "intensities", intensity.size(), rows, true);
    std::vector<int> keep;
    keep.reserve(static_cast<size_t>(rows));
    const bool active = std::isfinite(threshold) && intensity.size() == rows;
    for (Eigen::Index i = 0; i < rows; ++i) {
        if (!active || (std::isfinite(intensity(i)) && intensity(i) <= threshold))
            keep.push_back(static_cast<int>(i));
    }
    return keep;
}

double GroundGrid::heightAt(double x, double y) const {
    if (z.size() == 0) return kNaN;
    const auto c = static_cast<Eigen::Index>(std::floor((x - origin.x()) / cell));
    const auto r = static_cast<Eigen::Index>(std::floor((y - origin.y()) / cell));
    if (r < 0 || c < 0 || r >= z.rows() || c >= z.cols()) return kNaN;
    return z(r, c);
}

namespace {

// Rows of the lowest point per XY cell, the min-grid the morphological filter works on, and the
// usable rows (finite, within max range). A dense grid over the points' bounding box; a hash map
// when that box is huge (e.g. a wide map cloud).
std::vector<int> lowestPerCell(const Eigen::Ref<const Points3> &points, double cell, double range2,
                               std::vector<int> &usable) {
    const Eigen::Index n = points.rows();
    double bx0 = std::numeric_limits<double>::max(), by0 = bx0;
    double bx1 = std::numeric_limits<double>::lowest(), by1 = bx1;
    usable.clear();
    usable.reserve(static_cast<size_t>(n));
    for (Eigen::Index i = 0; i < n; ++i) {
        if (!finiteRow(points, i)) continue;
        const double x = points(i, 0), y = points(i, 1);
        if (std::isfinite(range2) && x * x + y * y > range2) continue;
        usable.push_back(static_cast<int>(i));
        bx0 = std::min(bx0, x), bx1 = std::max(bx1, x);
        by0 = std::min(by0, y), by1 = std::max(by1, y);
    }
    std::vector<int> cell_rows;
    if (usable.empty()) return cell_rows;
    const double gx0 = std::floor(bx0 / cell), gy0 = std::floor(by0 / cell);
    const double gcols = std::floor(bx1 / cell) - gx0 + 1;
    const double grows = std::floor(by1 / cell) - gy0 + 1;
    if (gcols * grows <= 4e6) {
        const auto nc = static_cast<std::int64_t>(gcols);
        std::vector<int> low(static_cast<size_t>(nc * static_cast<std::int64_t>(grows)), -1);
        for (int i : usable) {
            const auto c = static_cast<std::int64_t>(std::floor(points(i, 0) / cell) - gx0);
            const auto r = static_cast<std::int64_t>(std::floor(points(i, 1) / cell) - gy0);
            int &slot = low[static_cast<size_t>(r * nc + c)];
            if (slot < 0 || points(i, 2) < points(slot, 2)) slot = i;
        }
        for (int row : low)
            if (row >= 0) cell_rows.push_back(row);
        return cell_rows;
    }
    std::unordered_map<std::uint64_t, int> lowest;
    lowest.reserve(usable.size() / 4 + 16);
    for (int i : usable) {
        const auto cx = static_cast<std::int64_t>(std::floor(points(i, 0) / cell));
        const auto cy = static_cast<std::int64_t>(std::floor(points(i, 1) / cell));
        auto [it, inserted] = lowest.emplace(cellKey2(cx, cy), i);
        if (!inserted && points(i, 2) < points(it->second, 2)) it->second = i;
    }
    for (const auto &[key, row] : lowest) {
        (void)key;
        cell_rows.push_back(row);
    }
    return cell_rows;
}

// Dense grid of the ground cells' heights over their bounding box (NaN elsewhere); false when
// that box is absurdly large (> 3.5 km wide at 0.5 m cells).
bool groundHeightGrid(const Eigen::Ref<const Points3> &points, const std::vector<int> &rows_of,
                      double cell, GroundGrid &g) {
    double xmin = std::numeric_limits<double>::max(), ymin = xmin;
    double xmax = std::numeric_limits<double>::lowest(), ymax = xmax;
    for (int row : rows_of) {
        xmin = std::min(xmin, points(row, 0)), xmax = std::max(xmax, points(row, 0));
        ymin = std::min(ymin, points(row, 1)), ymax = std::max(ymax, points(row, 1));
    }
    g.cell = cell;
    g.origin = Eigen::Vector2d(std::floor(xmin / cell) * cell, std::floor(ymin / cell) * cell);
    const auto cols = static_cast<Eigen::Index>(std::floor((xmax - g.origin.x()) / cell)) + 1;
    const auto rows = static_cast<Eigen::Index>(std::floor((ymax - g.origin.y()) / cell)) + 1;
    if (static_cast<double>(rows) * static_cast<double>(cols) > 5e7) return false;
    g.z.setConstant(rows, cols, kNaN);
    for (int row : rows_of) {
        const auto c =
            static_cast<Eigen::Index>(std::floor((points(row, 0) - g.origin.x()) / cell));
        const auto r =
            static_cast<Eigen::Index>(std::floor((points(row, 1) - g.origin.y()) / cell));
        if (r >= 0 && c >= 0 && r < rows && c < cols) g.z(r, c) = points(row, 2);
    }
    return true;
}

// Small islands of "ground" cells are the lowest returns of stems in the blind circle around the
// sensor, where the filter has no true ground to compare with: components (cells within two
// cells of each other) smaller than `min_cells` become unknown. The components are found on a
// row-major mask with a border of two closed cells (no bounds checks); which cells a component
// holds does not depend on the order they are found in, so neither does the result.
void dropSmallIslands(Eigen::MatrixXd &z, int min_cells) {
    const Eigen::Index rows = z.rows(), cols = z.cols(), stride = cols + 4;
    std::vector<char> open(static_cast<size_t>((rows + 4) * stride), 0);  // finite, not yet taken
    for (Eigen::Index c = 0; c < cols; ++c)
        for (Eigen::Index r = 0; r < rows; ++r)
            open[static_cast<size_t>((r + 2) * stride + c + 2)] = std::isfinite(z(r, c)) ? 1 : 0;
    std::array<Eigen::Index, 24> around{};
    size_t n_around = 0;
    for (Eigen::Index dr = -2; dr <= 2; ++dr)
        for (Eigen::Index dc = -2; dc <= 2; ++dc)
            if (dr != 0 || dc != 0) around[n_around++] = dr * stride + dc;
    std::vector<Eigen::Index> stack, members;
    for (Eigen::Index start = 0; start < static_cast<Eigen::Index>(open.size()); ++start) {
        if (!open[static_cast<size_t>(start)]) continue;
        open[static_cast<size_t>(start)] = 0;
        stack.assign(1, start);
        members.assign(1, start);
        while (!stack.empty()) {
            const Eigen::Index at = stack.back();
            stack.pop_back();
            for (const Eigen::Index d : around)
                if (char &o = open[static_cast<size_t>(at + d)]; o) {
                    o = 0;
                    stack.push_back(at + d);
                    members.push_back(at + d);
                }
        }
        if (static_cast<int>(members.size()) < min_cells)
            for (const Eigen::Index at : members) z(at / stride - 2, at % stride - 2) = kNaN;
    }
}

// Holes (cells under stems, shadows) filled from known neighbours, one cell deeper per pass: an
// unknown cell with >= 2 known of its 8 neighbours takes their mean (from the previous pass's
// grid). On a row-major copy with a border of unknown cells (no bounds checks). After the first
// pass only the unknown neighbours of the cells just filled can change: later passes test those.
void fillHoles(Eigen::MatrixXd &z, int passes) {
    const Eigen::Index rows = z.rows() + 2, cols = z.cols() + 2;
    std::vector<double> cur(static_cast<size_t>(rows * cols), kNaN);
    std::vector<char> skip(cur.size(), 1);  // border, known or queued cells
    std::vector<Eigen::Index> todo;
    for (Eigen::Index r = 0; r < z.rows(); ++r)
        for (Eigen::Index c = 0; c < z.cols(); ++c) {
            const Eigen::Index at = (r + 1) * cols + c + 1;
            cur[at] = z(r, c);
            skip[at] = 0;
        }
    for (Eigen::Index at = 0; at < rows * cols; ++at)
        if (!skip[at] && !std::isfinite(cur[at])) todo.push_back(at);
    const Eigen::Index around[8] = {-cols - 1, -cols, -cols + 1, -1, 1, cols - 1, cols, cols + 1};
    std::vector<std::pair<Eigen::Index, double>> fills;
    for (int pass = 0; pass < passes && !todo.empty(); ++pass) {
        fills.clear();
        for (const Eigen::Index at : todo) {
            double s = 0;
            int cnt = 0;
            for (Eigen::Index dr = -1; dr <= 1; ++dr)  // the order of the sum as before
                for (Eigen::Index dc = -1; dc <= 1; ++dc) {
                    const double v = cur[at + dr * cols + dc];
                    if (std::isfinite(v)) s += v, ++cnt;
                }
            if (cnt >= 2) fills.push_back({at, s / cnt});
        }
        for (const auto &[at, v] : fills) cur[at] = v, skip[at] = 1;
        todo.clear();
        for (const auto &[at, v] : fills) {
            (void)v;
            for (const Eigen::Index d : around)
                if (!skip[at + d] && !std::isfinite(cur[at + d]))
                    skip[at + d] = 1, todo.push_back(at + d);
        }
        for (const Eigen::Index at : todo) skip[at] = 0;
    }
    for (Eigen::Index r = 0; r < z.rows(); ++r)
        for (Eigen::Index c = 0; c < z.cols(); ++c) z(r, c) = cur[(r + 1) * cols + c + 1];
}

// Ground: the usable points at most `max_height` above the grid's ground.
void labelGroundPoints(const Eigen::Ref<const Points3> &points, const std::vector<int> &usable,
                       double max_height, GroundSegmentation &out) {
    for (int i : usable) {
        const double h = points(i, 2) - out.grid.heightAt(points(i, 0), points(i, 1));
        if (std::isfinite(h) && h <= max_height) {
            out.is_ground[static_cast<size_t>(i)] = 1;
            ++out.ground_count;
        }
    }
}

}  // namespace

GroundSegmentation segmentGround(const Eigen::Ref<const Points3> &points, const GroundConfig &opt) {
    GroundSegmentation out;
    out.is_ground.assign(static_cast<size_t>(points.rows()), 0);
    const double cell = opt.cell_size_m > 0 ? opt.cell_size_m : 0.5;
    const double range2 = opt.max_range_m > 0 ? opt.max_range_m * opt.max_range_m : kNaN;
    std::vector<int> usable;
    const std::vector<int> cell_rows = lowestPerCell(points, cell, range2, usable);
    if (cell_rows.size() < 3) return out;
    std::vector<Eigen::Vector3f> cells;
    cells.reserve(cell_rows.size());
    for (int row : cell_rows) cells.push_back(points.row(row).transpose().cast<float>());
    std::vector<int> ground_rows;
    for (int k : morphologicalGround(cells, static_cast<float>(cell), opt))
        ground_rows.push_back(cell_rows[static_cast<size_t>(k)]);
    if (ground_rows.empty() || !groundHeightGrid(points, ground_rows, cell, out.grid)) return out;
    if (opt.min_component_cells > 1) dropSmallIslands(out.grid.z, opt.min_component_cells);
    fillHoles(out.grid.z, 4);
    labelGroundPoints(points, usable, opt.cell_height_m, out);
    return out;
}

Points3 thinGround(const Eigen::Ref<const Points3> &points, const std::vector<char> &is_ground,
                   double voxel_m) {
    const auto n_ground = static_cast<size_t>(std::count(is_ground.begin(), is_ground.end(), 1));
    VoxelIndex keep(n_ground);  // voxel -> its slot in `rows`
    std::vector<int> rows;      // lowest point per voxel, in first-seen order: deterministic output
    rows.reserve(n_ground);
    bool inserted = false;
    const double v = voxel_m > 0 ? voxel_m : 1e-6;
    for (Eigen::Index i = 0; i < points.rows(); ++i) {
        if (!is_ground[static_cast<size_t>(i)]) continue;
        const std::uint64_t key = voxelKey(points(i, 0), points(i, 1), points(i, 2), v);
        const int slot = keep.emplace(key, static_cast<int>(rows.size()), inserted);
        if (inserted)
            rows.push_back(static_cast<int>(i));
        else if (int &row = rows[static_cast<size_t>(slot)]; points(i, 2) < points(row, 2))
            row = static_cast<int>(i);
    }
    return selectRows(points, rows);
}

namespace {

// Candidate rows within the height band above the local ground (where `grid` knows it),
// thinned to the first row per voxel of `opt.voxel_m` (none when 0).
std::vector<int> thinnedBandRows(const Eigen::Ref<const Points3> &points,
                                 const std::vector<int> &candidates, const NormalFilterConfig &opt,
                                 const GroundGrid *grid) {
    std::vector<int> rows;
    rows.reserve(candidates.size());
    VoxelIndex voxels(opt.voxel_m > 0 ? candidates.size() : 0);
    bool fresh = false;
    const double v = opt.voxel_m;
    for (int i : candidates) {
        if (!finiteRow(points, i)) continue;
        if (grid != nullptr) {
            const double h = points(i, 2) - grid->heightAt(points(i, 0), points(i, 1));
            if (std::isfinite(h) && (h < opt.min_height_m || h > opt.max_height_m)) continue;
        }
        if (v > 0) {
            voxels.emplace(voxelKey(points(i, 0), points(i, 1), points(i, 2), v), 0, fresh);
            if (!fresh) continue;
        }
        rows.push_back(i);
    }
    return rows;
}

// Search radius per ring: geomspace(ring_min, ring_max, rings) edges, one radius per ring (one
// fixed radius in fixed mode).
struct RingRadii {
    std::vector<double> edges, radius;
    bool adaptive = true;
    double at(double x, double y) const {
        if (!adaptive) return radius.front();
        const double r = std::sqrt(x * x + y * y);
        const auto ring = std::upper_bound(edges.begin(), edges.end(), r) - edges.begin() - 1;
        return radius[static_cast<size_t>(
            std::clamp<long>(ring, 0, static_cast<long>(radius.size()) - 1))];
    }
};

RingRadii ringRadii(double theta_v_rad, const NormalFilterConfig &opt) {
    RingRadii out;
    out.adaptive = opt.adaptive;
    const int n_edges = std::max(2, opt.rings);
    const double lo = std::max(1e-3, opt.ring_min_m), hi = std::max(lo * 1.0001, opt.ring_max_m);
    for (int k = 0; k < n_edges; ++k)
        out.edges.push_back(lo * std::pow(hi / lo, static_cast<double>(k) / (n_edges - 1)));
    if (opt.adaptive) {
        for (int k = 0; k + 1 < n_edges; ++k) {
            const double d =
                opt.radius_scale * theta_v_rad * 0.5 * (out.edges[k] + out.edges[k + 1]);
            out.radius.push_back(std::clamp(d, opt.min_radius_m, opt.max_radius_m));
        }
    } else {
        out.radius.push_back(opt.fixed_radius_m);
    }
    return out;
}

// The normal of row `i` (towards the sensor) from its max_neighbours nearest rows of `tree`
// within `radius` (as PCL's radiusSearch with max_nn); false when fewer than min_neighbours lie
// there or the normal is not within max_normal_angle of horizontal (no vertical surface).
bool stemNormal(const Eigen::Ref<const Points3> &points, int i, const KdTree3 &tree, double radius,
                const NormalFilterConfig &opt, std::vector<std::pair<double, int>> &nn,
                Eigen::Vector3d &normal) {
    const Eigen::Vector3d p = points.row(i).transpose();
    const int found = tree.knn(p, std::max(opt.max_neighbours, 3), radius * radius, nn);
    if (found - 1 < opt.min_neighbours || found < 3) return false;  // the query is in nn
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
    eig.computeDirect(neighbourScatter(points, nn));  // closed form: ample for a normal, 3x faster
    const Eigen::Vector3d n = eig.eigenvectors().col(0);
    if (!n.allFinite() || std::abs(n.z()) > std::sin(opt.max_normal_angle_rad)) return false;
    normal = n.dot(p) > 0 ? Eigen::Vector3d(-n) : n;
    return true;
}

}  // namespace

NormalFilterResult normalFilter(const Eigen::Ref<const Points3> &points,
                                const std::vector<int> &candidates, double theta_v_rad,
                                const NormalFilterConfig &opt, const GroundGrid *grid,
                                Eigen::Index evidence_from) {
    NormalFilterResult out;
    const std::vector<int> rows = thinnedBandRows(points, candidates, opt, grid);
    const RingRadii radii = ringRadii(theta_v_rad, opt);
    out.radius_per_ring = radii.radius;
    if (rows.size() < 3) {
        out.normals.resize(0, 3);
        return out;
    }
    // The rows before `evidence_from` are tested on their own first (own_tree), as if the
    // evidence rows had never been seen; with every row as neighbours (tree) only after that.
    std::vector<int> own;
    for (const int i : rows)
        if (i < evidence_from) own.push_back(i);
    const bool has_evidence = own.size() < rows.size();
    KdTree3 tree, own_tree;
    own_tree.build(points, std::move(own));
    if (has_evidence) tree.build(points, rows);
    std::vector<std::pair<double, int>> nn;
    nn.reserve(2 * static_cast<size_t>(std::max(opt.max_neighbours, 3)));
    std::vector<int> with_evidence;  // rows that pass only with every row as neighbours
    std::vector<Eigen::Vector3d> normals, evidence_normals;
    Eigen::Vector3d n;
    for (const int i : rows) {
        const double radius = radii.at(points(i, 0), points(i, 1));
        if (i < evidence_from && stemNormal(points, i, own_tree, radius, opt, nn, n)) {
            out.kept.push_back(i);
            normals.push_back(n);
        } else if (has_evidence && stemNormal(points, i, tree, radius, opt, nn, n)) {
            with_evidence.push_back(i);
            evidence_normals.push_back(n);
        }
    }
    out.own_rows = out.kept.size();
    out.kept.insert(out.kept.end(), with_evidence.begin(), with_evidence.end());
    normals.insert(normals.end(), evidence_normals.begin(), evidence_normals.end());
    out.normals.resize(static_cast<Eigen::Index>(normals.size()), 3);
    for (size_t k = 0; k < normals.size(); ++k)
        out.normals.row(static_cast<Eigen::Index>(k)) = normals[k].transpose();
    return out;
}

}  // namespace forestslam::perception
