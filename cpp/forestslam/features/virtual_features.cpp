#include "forestslam/features/virtual_features.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include "forestslam/common/circle_fit.hpp"

namespace forestslam::features {

namespace {

struct Candidate {
    Eigen::Vector3d centre;
    double radius;
    int level;
    double rms;
};

std::int64_t cellKey(std::int64_t ix, std::int64_t iy) {
    return ((ix + (1LL << 30)) << 32) | ((iy + (1LL << 30)) & 0xFFFFFFFFLL);
}

// Circle fit of one cluster (rows of points); appends a candidate when it looks like a stem.
// sensor_side: in ring mode the centre must lie behind the surface seen from the origin.
void fitCluster(const Eigen::Ref<const Points3> &points, const std::vector<int> &rows, int level,
                bool sensor_side, const VirtualFeaturesConfig &cfg, std::vector<Candidate> &out) {
    if (static_cast<int>(rows.size()) < cfg.min_cluster_points) return;
    // Very dense clusters (TLS close to the station) are thinned: the fit needs no more.
    constexpr std::size_t kMaxFitPoints = 400;
    const std::size_t stride = rows.size() / kMaxFitPoints + 1;
    Points2 xy((rows.size() + stride - 1) / stride, 2);
    double z = 0.0, range = 0.0;
    Eigen::Index n = 0;
    for (std::size_t k = 0; k < rows.size(); k += stride, ++n) {
        xy.row(n) = points.row(rows[k]).head<2>();
        z += points(rows[k], 2);
        range += xy.row(n).norm();
    }
    xy.conservativeResize(n, 2);
    z /= static_cast<double>(n);
    range /= static_cast<double>(n);

    CircleFitConfig options;
    options.inlier_threshold_m = cfg.fit_inlier_m;
    options.min_radius_m = 0.5 * cfg.min_diameter_m;
    options.max_radius_m = 0.5 * cfg.max_diameter_m;
    options.max_ransac_iterations = 100;
    const CircleFit fit = fitCircle(xy, options);
    if (!fit.valid || fit.inliers < cfg.min_inlier_ratio * static_cast<double>(n) ||
        !(fit.rms_m <= cfg.max_fit_rms_m)) {
        return;
    }
    if (sensor_side && fit.centre.norm() <= range) return;
    out.push_back(
        {Eigen::Vector3d(fit.centre.x(), fit.centre.y(), z), fit.radius, level, fit.rms_m});
}

bool stemWidth(double width, const VirtualFeaturesConfig &cfg) {
    return width >= 0.5 * cfg.min_diameter_m && width <= 1.1 * cfg.max_diameter_m;
}

int findRoot(std::vector<int> &parent, int i) {
    while (parent[i] != i) i = parent[i] = parent[parent[i]];
    return i;
}

// Vertical continuity: candidates of different levels that may belong to one stem (close in
// x-y and z, radii within the taper) are linked; returns the linked groups (union-find roots in
// order, members in index order).
std::map<int, std::vector<int>> linkedGroups(const std::vector<Candidate> &cands,
                                             const VirtualFeaturesConfig &cfg) {
    const int n = static_cast<int>(cands.size());
    std::vector<int> parent(n);
    std::iota(parent.begin(), parent.end(), 0);
    const double cell = std::max(cfg.max_centre_shift_m, 1e-3);
    std::unordered_map<std::int64_t, std::vector<int>> grid;
    auto cellOf = [cell](double v) { return static_cast<std::int64_t>(std::floor(v / cell)); };
    for (int i = 0; i < n; ++i) {
        grid[cellKey(cellOf(cands[i].centre.x()), cellOf(cands[i].centre.y()))].push_back(i);
    }
    auto linked = [&cfg](const Candidate &a, const Candidate &b) {
        if (a.level == b.level) return false;
        if ((a.centre.head<2>() - b.centre.head<2>()).norm() > cfg.max_centre_shift_m) return false;
        const double dz = std::abs(a.centre.z() - b.centre.z());
        if (dz > cfg.max_vertical_gap_m) return false;
        return !(std::abs(a.radius - b.radius) > cfg.radius_tolerance_m + cfg.max_taper * dz);
    };
    for (int i = 0; i < n; ++i) {
        const auto cx = cellOf(cands[i].centre.x()), cy = cellOf(cands[i].centre.y());
        for (std::int64_t dx = -1; dx <= 1; ++dx) {
            for (std::int64_t dy = -1; dy <= 1; ++dy) {
                auto it = grid.find(cellKey(cx + dx, cy + dy));
                if (it == grid.end()) continue;
                for (int j : it->second) {
                    if (j > i && linked(cands[i], cands[j]))
                        parent[findRoot(parent, i)] = findRoot(parent, j);
                }
            }
        }
    }
    std::map<int, std::vector<int>> groups;
    for (int i = 0; i < n; ++i) groups[findRoot(parent, i)].push_back(i);
    return groups;
}

// One stem of a linked group: its members within the radius tolerance of the group's median
// radius; false when they span too few levels or too little height.
bool stemOfGroup(const std::vector<Candidate> &cands, const std::vector<int> &members,
                 const VirtualFeaturesConfig &cfg, std::vector<int> &good, double &median_radius) {
    std::vector<double> radii;
    for (int i : members) radii.push_back(cands[i].radius);
    std::nth_element(radii.begin(), radii.begin() + radii.size() / 2, radii.end());
    median_radius = radii[radii.size() / 2];
    good.clear();
    std::vector<int> levels;
    double zmin = 1e300, zmax = -1e300;
    for (int i : members) {
        if (std::abs(cands[i].radius - median_radius) <= std::max(0.02, 0.3 * median_radius)) {
            good.push_back(i);
            levels.push_back(cands[i].level);
            zmin = std::min(zmin, cands[i].centre.z());
            zmax = std::max(zmax, cands[i].centre.z());
        }
    }
    std::sort(levels.begin(), levels.end());
    const auto distinct = std::unique(levels.begin(), levels.end()) - levels.begin();
    return distinct >= cfg.min_levels && zmax - zmin >= cfg.min_vertical_span_m;
}

// The kept candidates (rows of cands) with their stem ids, and the stems' mean centres and
// median radii, as the result arrays.
VirtualFeatures packFeatures(const std::vector<Candidate> &cands, const std::vector<int> &kept,
                             const std::vector<int> &kept_stem,
                             const std::vector<Eigen::Vector3d> &stem_mean,
                             const std::vector<double> &stem_radius) {
    VirtualFeatures out;
    const auto k = static_cast<Eigen::Index>(kept.size());
    out.centres.resize(k, 3);
    out.radii.resize(k);
    out.stem_ids.resize(k);
    out.levels.resize(k);
    out.rms.resize(k);
    for (Eigen::Index r = 0; r < k; ++r) {
        const auto &c = cands[kept[r]];
        out.centres.row(r) = c.centre.transpose();
        out.radii[r] = c.radius;
        out.stem_ids[r] = kept_stem[r];
        out.levels[r] = c.level;
        out.rms[r] = c.rms;
    }
    const auto s = static_cast<Eigen::Index>(stem_mean.size());
    out.stems.resize(s, 3);
    out.stem_radii.resize(s);
    for (Eigen::Index r = 0; r < s; ++r) {
        out.stems.row(r) = stem_mean[r].transpose();
        out.stem_radii[r] = stem_radius[r];
    }
    return out;
}

// Vertical continuity: link candidates of different levels, keep groups spanning enough levels.
VirtualFeatures linkStems(const std::vector<Candidate> &cands, const VirtualFeaturesConfig &cfg) {
    std::vector<int> kept, kept_stem, good;
    std::vector<Eigen::Vector3d> stem_mean;
    std::vector<double> stem_radius;
    for (const auto &[root, members] : linkedGroups(cands, cfg)) {
        double median_radius = 0.0;
        if (!stemOfGroup(cands, members, cfg, good, median_radius)) continue;
        const int id = static_cast<int>(stem_mean.size());
        Eigen::Vector3d mean = Eigen::Vector3d::Zero();
        for (int i : good) {
            kept.push_back(i);
            kept_stem.push_back(id);
            mean += cands[i].centre;
        }
        stem_mean.push_back(mean / static_cast<double>(good.size()));
        stem_radius.push_back(median_radius);
    }
    return packFeatures(cands, kept, kept_stem, stem_mean, stem_radius);
}

}  // namespace

VirtualFeatures extractVirtualFeaturesRings(const Eigen::Ref<const Points3> &points,
                                            const std::vector<std::uint16_t> &rings,
                                            const VirtualFeaturesConfig &cfg) {
    if (static_cast<Eigen::Index>(rings.size()) != points.rows())
        throw std::invalid_argument("extractVirtualFeaturesRings: " + std::to_string(rings.size()) +
                                    " rings for " + std::to_string(points.rows()) + " points");
    std::vector<Candidate> cands;
    std::map<std::uint16_t, std::vector<int>> by_ring;
    for (Eigen::Index i = 0; i < points.rows(); ++i) {
        if (points.row(i).allFinite() && points.row(i).head<2>().squaredNorm() > 1e-6) {
            by_ring[rings[i]].push_back(static_cast<int>(i));
        }
    }
    std::vector<double> azimuth(static_cast<std::size_t>(points.rows()), 0.0);
    for (auto &[ring, rows] : by_ring) {
        for (int i : rows) azimuth[i] = std::atan2(points(i, 1), points(i, 0));
        std::sort(rows.begin(), rows.end(), [&](int a, int b) { return azimuth[a] < azimuth[b]; });
        std::vector<int> run;
        auto flush = [&]() {
            if (run.size() >= 2) {
                const double width = (points.row(run.front()) - points.row(run.back())).norm();
                if (stemWidth(width, cfg)) fitCluster(points, run, ring, true, cfg, cands);
            }
            run.clear();
        };
        for (int i : rows) {
            if (!run.empty()) {
                const double range = points.row(i).norm();
                const double gap = cfg.gap_m + cfg.gap_range_ratio * range;
                if ((points.row(i) - points.row(run.back())).norm() > gap) flush();
            }
            run.push_back(i);
        }
        flush();
    }
    return linkStems(cands, cfg);
}

VirtualFeatures extractVirtualFeaturesLayers(const Eigen::Ref<const Points3> &points,
                                             const VirtualFeaturesConfig &cfg) {
    std::vector<Candidate> cands;
    if (!(cfg.layer_step_m > 0) || !(cfg.cell_m > 0)) return linkStems(cands, cfg);
    std::map<std::int64_t, std::vector<int>> by_layer;
    const double half = 0.5 * cfg.layer_thickness_m;
    for (Eigen::Index i = 0; i < points.rows(); ++i) {
        if (!points.row(i).allFinite()) continue;
        const double z = points(i, 2);
        if (z < cfg.min_z_m || z > cfg.max_z_m) continue;
        const auto layer = static_cast<std::int64_t>(std::llround(z / cfg.layer_step_m));
        if (std::abs(z - layer * cfg.layer_step_m) <= half) {
            by_layer[layer].push_back(static_cast<int>(i));
        }
    }
    auto cellOf = [&](double v) { return static_cast<std::int64_t>(std::floor(v / cfg.cell_m)); };
    for (const auto &[layer, rows] : by_layer) {
        std::unordered_map<std::int64_t, std::vector<int>> cells;
        for (int i : rows) cells[cellKey(cellOf(points(i, 0)), cellOf(points(i, 1)))].push_back(i);
        std::unordered_map<std::int64_t, char> visited;
        for (const auto &[key, members] : cells) {
            if (visited.count(key)) continue;
            // Connected occupied cells (8-neighbourhood) form one cluster.
            std::vector<int> cluster;
            std::vector<std::int64_t> stack{key};
            visited[key] = 1;
            double xmin = 1e300, xmax = -1e300, ymin = 1e300, ymax = -1e300;
            bool too_wide = false;
            while (!stack.empty()) {
                const std::int64_t k = stack.back();
                stack.pop_back();
                for (int i : cells[k]) {
                    cluster.push_back(i);
                    xmin = std::min(xmin, points(i, 0));
                    xmax = std::max(xmax, points(i, 0));
                    ymin = std::min(ymin, points(i, 1));
                    ymax = std::max(ymax, points(i, 1));
                }
                if (std::max(xmax - xmin, ymax - ymin) > 1.5 * cfg.max_diameter_m) too_wide = true;
                const std::int64_t ix = (k >> 32) - (1LL << 30);
                const std::int64_t iy = (k & 0xFFFFFFFFLL) - (1LL << 30);
                for (std::int64_t dx = -1; dx <= 1; ++dx) {
                    for (std::int64_t dy = -1; dy <= 1; ++dy) {
                        const std::int64_t nk = cellKey(ix + dx, iy + dy);
                        if (visited.count(nk) || !cells.count(nk)) continue;
                        visited[nk] = 1;
                        stack.push_back(nk);
                    }
                }
            }
            if (too_wide) continue;
            const double width = std::max(xmax - xmin, ymax - ymin);
            if (stemWidth(width, cfg)) {
                fitCluster(points, cluster, static_cast<int>(layer), false, cfg, cands);
            }
        }
    }
    return linkStems(cands, cfg);
}

}  // namespace forestslam::features
