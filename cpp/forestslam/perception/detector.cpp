#include "forestslam/perception/detector.hpp"

#include <pcl/console/print.h>

#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <ctime>
#include <limits>
#include <map>
#include <unordered_map>

#include "forestslam/common/median.hpp"
#include "forestslam/common/voxel_key.hpp"
#include "forestslam/perception/preprocess.hpp"
#include "forestslam/perception/segmentation.hpp"

namespace forestslam::perception {
namespace {

using Clock = std::chrono::steady_clock;

// CPU time of this thread: the cost on one core, whatever else the machine is doing.
double threadCpuMs() {
    timespec ts{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return 1e3 * static_cast<double>(ts.tv_sec) + 1e-6 * static_cast<double>(ts.tv_nsec);
}

struct StageClock {
    Clock::time_point wall = Clock::now();
    double cpu = threadCpuMs();
    void lap(Detection &det, const std::string &stage) {
        const auto now = Clock::now();
        const double c = threadCpuMs();
        det.timing_ms[stage] = std::chrono::duration<double, std::milli>(now - wall).count();
        det.cpu_ms[stage] = c - cpu;
        wall = now;
        cpu = c;
    }
};

double bandMiddle(const DiameterConfig &o) { return 0.5 * (o.band_low_m + o.band_high_m); }

// Base height (breast height - 1.3 m) of a stem whose ground is unknown.
double baseWithoutGround(const Points3 &p, const PerceptionConfig &opt, BreastHeightSource &src) {
    const double lo = p.col(2).minCoeff(), hi = p.col(2).maxCoeff();
    if (std::isfinite(opt.breast_height_z)) {
        src = BreastHeightSource::Explicit;
        return opt.breast_height_z - bandMiddle(opt.diameter);
    }
    // A stem reaching above the band stands on its lowest point; a shorter piece is a slice
    // cut around breast height, so its middle is taken.
    if (hi - lo >= opt.diameter.band_high_m) {
        src = BreastHeightSource::LowestPoint;
        return lo;
    }
    src = BreastHeightSource::Slice;
    return 0.5 * (lo + hi) - bandMiddle(opt.diameter);
}

// Stems of a map cloud without ground: each 3D cluster (points thinned to slice_voxel_m) whose
// breast-height section is a circle (valid fit, arc coverage, most band points within its
// gate). No SVD elongation test: a breast-height slice is wider than it is tall.
std::vector<Stem> groundlessStems(const Points3 &pts, const PerceptionConfig &opt) {
    // Thin to slice_voxel_m; cluster one representative per coarser voxel (a quarter of the
    // clustering tolerance: dense clouds make radius searches quadratic), then every thinned
    // point joins its representative's cluster.
    const SegmentationConfig &so = opt.segmentation;
    const double fine = std::max(opt.slice_voxel_m, 1e-4);
    const double coarse = std::max(fine, 0.25 * so.euclidean_tolerance_m);
    std::unordered_map<std::uint64_t, char> fine_seen;
    std::unordered_map<std::uint64_t, int> coarse_rep;
    std::vector<int> rows, rep_rows, rep_of;  // rep_of: per thinned point, its representative
    for (Eigen::Index i = 0; i < pts.rows(); ++i) {
        if (!fine_seen.emplace(voxelKey(pts(i, 0), pts(i, 1), pts(i, 2), fine), 1).second) continue;
        const auto [it, inserted] = coarse_rep.emplace(
            voxelKey(pts(i, 0), pts(i, 1), pts(i, 2), coarse), static_cast<int>(rep_rows.size()));
        if (inserted) rep_rows.push_back(static_cast<int>(i));
        rows.push_back(static_cast<int>(i));
        rep_of.push_back(it->second);
    }
    const Points3 reps = selectRows(pts, rep_rows);
    const Clusters rep_clusters =
        euclideanClusters(reps, so.euclidean_tolerance_m, std::max(2, so.min_points / 4));
    std::vector<int> cluster_of(rep_rows.size(), -1);
    for (size_t k = 0; k < rep_clusters.size(); ++k)
        for (int r : rep_clusters[k]) cluster_of[static_cast<size_t>(r)] = static_cast<int>(k);
    Clusters clusters(rep_clusters.size());
    for (size_t j = 0; j < rows.size(); ++j) {
        const int k = cluster_of[static_cast<size_t>(rep_of[j])];
        if (k >= 0) clusters[static_cast<size_t>(k)].push_back(rows[j]);
    }
    DiameterConfig dopt = opt.diameter;
    dopt.min_arc_coverage = std::max(dopt.min_arc_coverage, dopt.map_min_arc_coverage);
    std::vector<Stem> out;
    for (const auto &c : clusters) {
        if (static_cast<int>(c.size()) < so.min_points) continue;
        Stem st;
        st.points = selectRows(pts, c);
        st.base_z = baseWithoutGround(st.points, opt, st.breast_source);
        st.diameter =
            estimateDiameter(st.points, Points3(0, 3), st.base_z, Eigen::Vector3d::UnitZ(), dopt);
        const DiameterFit &f = st.diameter.circle;
        if (!f.valid || f.inliers < opt.slice_min_inlier_ratio * st.diameter.band_points) continue;
        st.shape = clusterShape(pts, c, Eigen::Vector3d::UnitZ());
        st.breast = st.diameter.centre;
        out.push_back(std::move(st));
    }
    return out;
}

}  // namespace

Eigen::Vector3d groundNormal(const Eigen::Ref<const Points3> &ground) {
    if (ground.rows() < 10) return Eigen::Vector3d::UnitZ();
    const Eigen::RowVector3d mean = ground.colwise().mean();
    const Eigen::MatrixXd c = ground.rowwise() - mean;
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(c.transpose() * c);
    Eigen::Vector3d n = eig.eigenvectors().col(0);
    if (n.z() < 0) n = -n;
    // A cloud of ground points that is not a plane (a slope + bank) or is steep: keep +z.
    if (n.z() < std::cos(0.5236) || !n.allFinite()) return Eigen::Vector3d::UnitZ();
    return n;
}

namespace {

// Points of one call relative to a local origin (map clouds), with their rings.
struct Input {
    Points3 pts;
    Eigen::RowVector3d origin = Eigen::RowVector3d::Zero();
    Eigen::VectorXi ring;            // per row of pts; empty when the input has no rings
    Points3 bright = Points3(0, 3);  // finite rows the intensity filter left out
    Eigen::VectorXi bright_ring;     // per row of bright; empty when the input has no rings
    // Rows of pts the intensity filter kept: all, unless the removed ones were appended after
    // them for the clustering (see appendRemovedReturns).
    Eigen::Index kept_rows = 0;
};

// 1. Finite rows within the intensity threshold (and apart, those above it: the diameter stage
// gives back the ones on a stem's surface, see onStemSurface). Map clouds come in projected
// coordinates (UTM: 3.8e6 m): PCL works in float, so work relative to a local origin and add it
// back to the outputs.
Input selectInput(const Eigen::Ref<const Points3> &points,
                  const Eigen::Ref<const Eigen::VectorXd> &intensity,
                  const Eigen::Ref<const Eigen::VectorXi> &ring, bool scan_centred,
                  const PerceptionConfig &opt, Detection &det) {
    std::vector<int> keep = intensityFilter(intensity, opt.intensity_threshold, points.rows());
    det.after_intensity = static_cast<int>(keep.size());
    std::vector<int> finite;
    finite.reserve(keep.size());
    for (int i : keep)
        if (points.row(i).allFinite()) finite.push_back(i);
    det.finite_points = static_cast<int>(finite.size());
    Input in;
    in.pts = selectRows(points, finite);
    in.kept_rows = in.pts.rows();
    std::vector<int> bright;
    if (keep.size() < static_cast<size_t>(points.rows())) {
        size_t k = 0;
        for (Eigen::Index i = 0; i < points.rows(); ++i) {
            if (k < keep.size() && keep[k] == i) {
                ++k;
            } else if (points.row(i).allFinite()) {
                bright.push_back(static_cast<int>(i));
            }
        }
        in.bright = selectRows(points, bright);
    }
    if (!scan_centred && in.pts.rows() > 0) {
        in.origin = in.pts.colwise().minCoeff().array().floor().matrix();
        in.pts.rowwise() -= in.origin;
        in.bright.rowwise() -= in.origin;
    }
    if (ring.size() == points.rows()) {
        in.ring.resize(static_cast<Eigen::Index>(finite.size()));
        for (size_t k = 0; k < finite.size(); ++k)
            in.ring(static_cast<Eigen::Index>(k)) = ring(finite[k]);
        in.bright_ring.resize(static_cast<Eigen::Index>(bright.size()));
        for (size_t k = 0; k < bright.size(); ++k)
            in.bright_ring(static_cast<Eigen::Index>(k)) = ring(bright[k]);
    }
    return in;
}

// When the returns the intensity filter removed from a cluster count as its bark (see
// removedFaceTheSensor): their median off-centre at least this much below the kept ones'
// (0 faces the sensor, 1 grazes the edge), ...
constexpr double kCentreMargin = 0.1;
// ... on at least this many scan lines holding both, ...
constexpr int kMinMixedLines = 2;
// ... and a rank-sum z at least this (one-sided p ~ 0.02 under "intensity does not depend on
// where a return meets the section", as for foliage).
constexpr double kMinCentreZ = 2.0;

// True when the clustering sees the returns the intensity filter removed too, and intensity is
// only evidence per cluster (see refineWithEvidence): when the config asks for it, on single
// scans with a range image and beam elevations in which the filter removed something. A fixed
// threshold cannot know another sensor's or simulator's intensity scale: under a brighter gain it
// removes the bark facing the sensor and breaks each stem into edge strips before any geometry is
// seen. Map and TLS clouds keep the filter before the clustering.
bool intensityAsEvidence(const Input &in, const SensorGeometry &sensor, bool scan_centred,
                         const PerceptionConfig &opt) {
    return opt.intensity_as_evidence && scan_centred && sensor.has_range_image &&
           !sensor.vertical_angles_rad.empty() && in.bright.rows() > 0;
}

// The removed returns appended after the kept ones (pts, ring), non-ground unless within the
// ground height of the ground grid found from the kept returns (ground and its outputs stay
// those of the kept returns).
void appendRemovedReturns(Input &in, GroundSegmentation &gs, double ground_height_m) {
    const Eigen::Index n = in.pts.rows(), m = in.bright.rows();
    Points3 all(n + m, 3);
    all << in.pts, in.bright;
    in.pts = std::move(all);
    if (in.ring.size() == n && in.bright_ring.size() == m) {
        Eigen::VectorXi ring(n + m);
        ring << in.ring, in.bright_ring;
        in.ring = std::move(ring);
    }
    gs.is_ground.resize(static_cast<size_t>(n + m), 0);
    for (Eigen::Index i = 0; i < m; ++i) {
        const double h = in.bright(i, 2) - gs.grid.heightAt(in.bright(i, 0), in.bright(i, 1));
        gs.is_ground[static_cast<size_t>(n + i)] = std::isfinite(h) && h <= ground_height_m;
    }
}

// 2. Ground: segmentation, thinned ground points and the ground normal.
GroundSegmentation findGround(const Points3 &pts, bool scan_centred, const PerceptionConfig &opt,
                              Detection &det) {
    GroundConfig gopt = opt.ground;
    if (!scan_centred) gopt.max_range_m = 0;
    GroundSegmentation gs = segmentGround(pts, gopt);
    det.ground_points = gs.ground_count;
    det.ground = thinGround(pts, gs.is_ground, opt.ground_voxel_m);
    det.up = groundNormal(det.ground);
    return gs;
}

// 3. Adaptive normals and filter on the non-ground points within range. Rows from `kept_rows`
// on (the removed returns, see appendRemovedReturns) are evidence (see normalFilter).
NormalFilterResult filterStemPoints(const Points3 &pts, Eigen::Index kept_rows,
                                    const GroundSegmentation &gs, const SensorGeometry &sensor,
                                    bool scan_centred, const PerceptionConfig &opt) {
    std::vector<int> candidates;
    candidates.reserve(static_cast<size_t>(pts.rows()));
    const double range_max = scan_centred ? opt.segmentation.max_range_m : 0.0;
    const double range2 = range_max * range_max;  // squared: std::hypot is slow per point
    for (Eigen::Index i = 0; i < pts.rows(); ++i) {
        if (gs.is_ground[static_cast<size_t>(i)]) continue;
        if (range_max > 0 && pts(i, 0) * pts(i, 0) + pts(i, 1) * pts(i, 1) > range2) continue;
        candidates.push_back(static_cast<int>(i));
    }
    NormalFilterConfig fopt = opt.filter;
    if (!scan_centred) {
        fopt.adaptive = false;
        fopt.voxel_m = std::max(fopt.voxel_m, fopt.map_voxel_m);
    }
    return normalFilter(pts, candidates, sensor.theta_v_rad, fopt,
                        gs.grid.z.size() > 0 ? &gs.grid : nullptr, kept_rows);
}

// 4. Coarse clusters: range image for single scans, 3D otherwise. `filtered`: the first rows of
// the normal filter's output (nf.kept). `line` (may be null): the range-image row (scan line)
// of each filtered point.
Clusters coarseClusters(const Points3 &filtered, const NormalFilterResult &nf,
                        const Eigen::VectorXi &ring, const SensorGeometry &sensor,
                        bool scan_centred, const SegmentationConfig &so,
                        std::vector<int> *line = nullptr) {
    if (!(sensor.has_range_image && scan_centred))
        return euclideanClusters(filtered, so.euclidean_tolerance_m,
                                 std::max(2, so.min_points / 2));
    Eigen::VectorXi ring_f;
    if (ring.size() > 0) {
        ring_f.resize(filtered.rows());
        for (Eigen::Index k = 0; k < filtered.rows(); ++k)
            ring_f(k) = ring(nf.kept[static_cast<size_t>(k)]);
    }
    const RangeImageProjection proj = projectToRangeImage(filtered, ring_f, sensor);
    if (line != nullptr) *line = proj.row;
    return rangeImageClusters(filtered, proj, sensor, so, std::max(2, so.min_points / 2));
}

SilhouetteSensor silhouetteSensor(const SensorGeometry &sensor);

// Stems among `rows` of `filtered` by the SVD test.
void keepStems(const Points3 &filtered, std::vector<int> rows, const SegmentationConfig &so,
               Detection &det, Clusters &stems) {
    const ClusterShape s = clusterShape(filtered, rows, det.up);
    if (isStem(s, static_cast<int>(rows.size()), so)) stems.push_back(std::move(rows));
}

// Whether the removed returns of a cluster lie nearer the middle of their scan lines than its
// kept ones, beyond chance. Off-centre of a return: |bearing - middle| / half the line's width
// (0 faces the sensor, 1 grazes a convex section's edge), on the lines holding both kept and
// removed returns (`line`: per row of `filtered`, its scan line); at least kMinMixedLines such
// lines, the medians kCentreMargin apart, and the rank-sum (Mann-Whitney) z of the kept ones
// being farther off >= kMinCentreZ: a handful of dark returns among foliage is not evidence.
bool removedFaceTheSensor(const Points3 &filtered, const std::vector<int> &line,
                          const std::vector<int> &kept, const std::vector<int> &removed) {
    Eigen::Vector2d m = Eigen::Vector2d::Zero();
    for (int r : kept) m += filtered.block<1, 2>(r, 0).transpose();
    for (int r : removed) m += filtered.block<1, 2>(r, 0).transpose();
    const double bearing = std::atan2(m.y(), m.x());
    std::map<int, std::vector<std::pair<double, bool>>> lines;  // line -> (bearing, kept)
    auto add = [&](int r, bool is_kept) {
        const double a = std::atan2(filtered(r, 1), filtered(r, 0)) - bearing;
        lines[line[static_cast<size_t>(r)]].push_back(
            {std::atan2(std::sin(a), std::cos(a)), is_kept});
    };
    for (int r : kept) add(r, true);
    for (int r : removed) add(r, false);
    int mixed = 0;
    std::vector<std::pair<double, bool>> off;  // (off-centre, kept)
    for (const auto &[l, rets] : lines) {
        const auto n_kept =
            std::count_if(rets.begin(), rets.end(), [](const auto &x) { return x.second; });
        if (l < 0 || n_kept == 0 || n_kept == static_cast<std::ptrdiff_t>(rets.size())) continue;
        ++mixed;
        const auto [lo, hi] = std::minmax_element(rets.begin(), rets.end());
        const double half = 0.5 * (hi->first - lo->first), mid = 0.5 * (hi->first + lo->first);
        if (!(half > 0)) continue;
        for (const auto &[a, is_kept] : rets) off.push_back({std::abs(a - mid) / half, is_kept});
    }
    if (mixed < kMinMixedLines) return false;
    std::vector<double> off_kept, off_removed;
    for (const auto &[o, is_kept] : off) (is_kept ? off_kept : off_removed).push_back(o);
    if (median(off_removed) + kCentreMargin > median(off_kept)) return false;
    // Rank sum of the kept ones (ties get their mean rank).
    std::sort(off.begin(), off.end());
    double rank_sum = 0;
    for (size_t i = 0; i < off.size();) {
        size_t j = i;
        while (j < off.size() && off[j].first == off[i].first) ++j;
        const double mean_rank = 0.5 * static_cast<double>(i + j + 1);
        for (size_t k = i; k < j; ++k)
            if (off[k].second) rank_sum += mean_rank;
        i = j;
    }
    const double n1 = static_cast<double>(off_kept.size()),
                 n2 = static_cast<double>(off_removed.size());
    const double u = rank_sum - 0.5 * n1 * (n1 + 1);
    const double z = (u - 0.5 * n1 * n2) / std::sqrt(n1 * n2 * (n1 + n2 + 1) / 12.0);
    return z >= kMinCentreZ;
}

// A refined cluster holding returns the intensity filter removed (rows >= kept_rows of the
// input; see intensityAsEvidence): geometry decides, intensity is evidence. Bark returns more
// light the more squarely a beam meets it (any incidence-dependent intensity, whatever its
// scale), so a threshold that cuts into a stem's bark removes the returns facing the sensor,
// in the middle of each scan line, and keeps the grazing ones at its edges; foliage has no
// such order. When the removed returns lie nearer the middle of their lines than the kept ones
// (removedFaceTheSensor), those on the surface the kept ones span (onStemSurface) join them
// and together they are tested as one stem (appended to `stems`); otherwise the cluster adds
// nothing: what its kept returns hold was found without the removed ones (stemPieces).
void evidenceStem(const Points3 &filtered, const NormalFilterResult &nf,
                  const std::vector<int> &line, Eigen::Index kept_rows, const std::vector<int> &sub,
                  const SilhouetteSensor &sensor, const SegmentationConfig &so,
                  const Eigen::Vector3d &up, Clusters &stems) {
    std::vector<int> kept, removed;
    for (int r : sub) (nf.kept[static_cast<size_t>(r)] < kept_rows ? kept : removed).push_back(r);
    if (removed.empty() || kept.size() < 2 || !removedFaceTheSensor(filtered, line, kept, removed))
        return;
    std::vector<int> rows = kept;
    for (int k : onStemSurface(selectRows(filtered, kept), selectRows(filtered, removed), sensor))
        rows.push_back(removed[static_cast<size_t>(k)]);
    const ClusterShape s = clusterShape(filtered, rows, up);
    if (rows.size() > kept.size() && isStem(s, static_cast<int>(rows.size()), so))
        stems.push_back(std::move(rows));
}

// DBSCAN sub-clusters of the coarse clusters (eps from the range for single scans).
template <typename Visit>
void refinedClusters(const Points3 &filtered, const Clusters &coarse, const SensorGeometry &sensor,
                     bool scan_centred, const SegmentationConfig &so, Visit visit) {
    for (const auto &c : coarse) {
        const double eps = (sensor.has_range_image && scan_centred)
                               ? adaptiveEps(filtered, c, sensor.theta_v_rad, so)
                               : so.map_dbscan_eps_m;
        for (auto &sub : dbscan(filtered, c, eps, so.dbscan_min_neighbours)) visit(std::move(sub));
    }
}

// 5. DBSCAN refinement and SVD classification: stem pieces (before the merge of one tree's).
Clusters stemPieces(const Points3 &filtered, const Clusters &coarse, const SensorGeometry &sensor,
                    bool scan_centred, const SegmentationConfig &so, Detection &det) {
    Clusters stems;
    refinedClusters(filtered, coarse, sensor, scan_centred, so, [&](std::vector<int> sub) {
        ++det.refined_clusters;
        keepStems(filtered, std::move(sub), so, det, stems);
    });
    return stems;
}

// 5b. With the removed returns as evidence: a piece the clustering of every return finds where
// removed returns are bark (see evidenceStem) replaces the pieces of the kept returns alone
// (`pieces`, rows of the first filtered rows: the same rows) that share a return with it. It
// stands alone when it shares none: under a bright gain the kept returns of a stem can be too
// few for a piece (its edges only). Every other piece is the kept returns' own: removed
// returns that are not the bark facing the sensor change nothing. When they were filtered and
// clustered with the kept returns, dark leaves among bright ones became sapling-like stems:
// they passed the normal filter with bright neighbours, and the joint clustering cut them into
// other pieces than alone (the false trees of the style-a loops, issue 15).
Clusters withEvidencePieces(const Points3 &filtered, const NormalFilterResult &nf,
                            const Eigen::VectorXi &ring, Eigen::Index kept_rows,
                            const SensorGeometry &sensor, const SegmentationConfig &so,
                            const Eigen::Vector3d &up, Clusters pieces) {
    std::vector<int> line;
    const Clusters coarse = coarseClusters(filtered, nf, ring, sensor, true, so, &line);
    Clusters evidence;
    const SilhouetteSensor silhouette = silhouetteSensor(sensor);
    refinedClusters(filtered, coarse, sensor, true, so, [&](const std::vector<int> &sub) {
        evidenceStem(filtered, nf, line, kept_rows, sub, silhouette, so, up, evidence);
    });
    if (evidence.empty()) return pieces;
    std::vector<char> taken(static_cast<size_t>(filtered.rows()), 0);
    for (const auto &e : evidence)
        for (int r : e) taken[static_cast<size_t>(r)] = 1;
    Clusters out;
    for (auto &p : pieces)
        if (std::none_of(p.begin(), p.end(), [&](int r) { return taken[static_cast<size_t>(r)]; }))
            out.push_back(std::move(p));
    for (auto &e : evidence) out.push_back(std::move(e));
    return out;
}

// Local ground height under a stem at `xy` (nearest ground points, wider, the ground grid, the
// plane of the ground seen farther out for the blind circle around the sensor); NaN if none.
double stemGroundHeight(const Detection &det, const GroundByX &ground_by_x,
                        const GroundSegmentation &gs, const Eigen::Vector2d &xy,
                        const SegmentationConfig &so) {
    double base = localGroundHeight(ground_by_x, xy, so.ground_search_m);
    if (!std::isfinite(base)) base = localGroundHeight(ground_by_x, xy, 2.0 * so.ground_search_m);
    if (!std::isfinite(base)) base = gs.grid.heightAt(xy.x(), xy.y());
    if (!std::isfinite(base)) base = planeGroundHeight(det.ground, xy, 12.0);
    return base;
}

// What the single-scan silhouette estimate needs from the sensor.
SilhouetteSensor silhouetteSensor(const SensorGeometry &sensor) {
    SilhouetteSensor silhouette;
    silhouette.vertical_angles_rad = sensor.vertical_angles_rad;
    silhouette.azimuth_step_rad =
        sensor.azimuth_step_rad > 0
            ? sensor.azimuth_step_rad
            : (sensor.image_cols > 0 ? sensor.horizontal_fov_rad / sensor.image_cols : 0.0);
    return silhouette;
}

// Rows of `p` with lo <= z <= hi.
Points3 rowsAtHeights(const Points3 &p, double lo, double hi) {
    std::vector<int> rows;
    for (Eigen::Index i = 0; i < p.rows(); ++i)
        if (p(i, 2) >= lo && p(i, 2) <= hi) rows.push_back(static_cast<int>(i));
    return selectRows(p, rows);
}

// True when some of `p` lie within `half` of height z.
bool reachesHeight(const Points3 &p, double z, double half) {
    return ((p.col(2).array() - z).abs() <= half).any();
}

// Every non-ground input return in the thinning voxel of one of a stem's points: each stem at
// the scan's full resolution, for its silhouette. The normal filter keeps the first return per
// voxel; where returns lie closer than a voxel (within about 14 m on a VLP-16 at 5 cm) that
// drops the outermost returns of a silhouette, which came out 1-1.6 cm small within 8 m
// (bench/dbh_near_range.py).
// Box of voxel indices. Keys wrap every 2^21 cells (voxel_key.hpp): within +-2^20 cells, a
// return outside the box shares no key with a voxel inside it.
struct VoxelBox {
    static constexpr std::int64_t kExact = std::int64_t{1} << 20;
    std::int64_t lo[3] = {kExact, kExact, kExact}, hi[3] = {-kExact, -kExact, -kExact};
    void add(const std::int64_t (&v)[3]) {
        for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], v[a]), hi[a] = std::max(hi[a], v[a]);
    }
    // True when no key of `v` can equal a key of the box's voxels (box and v within +-2^20).
    bool excludes(const std::int64_t (&v)[3]) const {
        bool outside = false;
        for (int a = 0; a < 3; ++a) {
            if (lo[a] <= -kExact || hi[a] >= kExact || v[a] <= -kExact || v[a] >= kExact)
                return false;
            outside = outside || v[a] < lo[a] || v[a] > hi[a];
        }
        return outside;
    }
};

// Returns the intensity filter removed (rows >= kept_rows) join only the stems that hold some.
std::vector<Points3> fullResolutionStems(const Points3 &pts, const GroundSegmentation &gs,
                                         const NormalFilterResult &nf, const Clusters &stems,
                                         Eigen::Index kept_rows, double voxel_m) {
    std::vector<Points3> out(stems.size());
    if (!(voxel_m > 0)) return out;  // nothing thinned: the stems' own points
    auto cell = [&](Eigen::Index i, std::int64_t (&v)[3]) {
        for (int a = 0; a < 3; ++a) v[a] = cellIndex(pts(i, a), voxel_m);
    };
    // Most returns lie outside the stems' voxel box and skip the hash look-up.
    std::unordered_map<std::uint64_t, int> stem_of;
    VoxelBox box;
    std::int64_t v[3];
    std::vector<char> holds_removed(stems.size(), 0);
    for (size_t k = 0; k < stems.size(); ++k)
        for (int r : stems[k]) {
            const int i = nf.kept[static_cast<size_t>(r)];
            if (i >= kept_rows) holds_removed[k] = 1;
            cell(i, v);
            box.add(v);
            stem_of.emplace(cellKey3(v[0], v[1], v[2]), static_cast<int>(k));
        }
    std::vector<std::vector<int>> rows(stems.size());
    for (Eigen::Index i = 0; i < pts.rows(); ++i) {
        if (gs.is_ground[static_cast<size_t>(i)]) continue;
        cell(i, v);
        if (box.excludes(v)) continue;
        const auto it = stem_of.find(cellKey3(v[0], v[1], v[2]));
        if (it != stem_of.end() && (i < kept_rows || holds_removed[it->second]))
            rows[static_cast<size_t>(it->second)].push_back(static_cast<int>(i));
    }
    for (size_t k = 0; k < stems.size(); ++k) out[k] = selectRows(pts, rows[k]);
    return out;
}

// Non-ground returns of a scan by azimuth column (one sensor step wide): where the occluders
// of a stem's silhouette and the returns seen through it are looked up. Rows of column c:
// rows[start[c] .. start[c + 1]), ascending.
struct AzimuthColumns {
    double step = 0;
    std::vector<int> start, rows;
    int count() const { return start.empty() ? 0 : static_cast<int>(start.size()) - 1; }
    int of(double az) const {
        const int n = count();
        return ((static_cast<int>(std::floor((az + M_PI) / step)) % n) + n) % n;
    }
};

// `skip` (may be null): rows flagged there are left out.
AzimuthColumns azimuthColumns(const Points3 &pts, const std::vector<char> *skip, double step) {
    AzimuthColumns c;
    if (!(step > 0)) return c;
    c.step = step;
    const size_t n = static_cast<size_t>(std::ceil(2 * M_PI / step));
    c.start.assign(n + 1, 0);
    std::vector<int> near, col;  // counting sort by column keeps each column's rows ascending
    for (Eigen::Index i = 0; i < pts.rows(); ++i) {
        if (skip != nullptr && (*skip)[static_cast<size_t>(i)]) continue;
        near.push_back(static_cast<int>(i));
        col.push_back(c.of(std::atan2(pts(i, 1), pts(i, 0))));
        ++c.start[static_cast<size_t>(col.back()) + 1];
    }
    for (size_t k = 0; k < n; ++k) c.start[k + 1] += c.start[k];
    c.rows.resize(near.size());
    std::vector<int> next(c.start.begin(), c.start.end() - 1);
    for (size_t j = 0; j < near.size(); ++j)
        c.rows[static_cast<size_t>(next[static_cast<size_t>(col[j])]++)] = near[j];
    return c;
}

// The bearings and horizontal ranges a stem's returns `seen` cover: computed once per stem and
// shared by its returnsAround look-ups (speed: one atan2 per return instead of one per look-up).
struct Sector {
    bool empty = true;
    double near2 = 0, far2 = 0, bearing = 0, lo = 0, hi = 0;
};

Sector sectorOf(const Points3 &seen) {
    Sector s;
    if (seen.rows() == 0) return s;
    s.empty = false;
    const Eigen::VectorXd d2_seen = seen.leftCols<2>().rowwise().squaredNorm();
    s.near2 = d2_seen.minCoeff(), s.far2 = d2_seen.maxCoeff();
    const Eigen::Vector2d m = seen.leftCols<2>().colwise().mean().transpose();
    s.bearing = std::atan2(m.y(), m.x());
    for (Eigen::Index i = 0; i < seen.rows(); ++i) {
        const double a = std::atan2(seen(i, 1), seen(i, 0)) - s.bearing;
        const double w = std::atan2(std::sin(a), std::cos(a));
        s.lo = std::min(s.lo, w), s.hi = std::max(s.hi, w);
    }
    return s;
}

// The returns within two azimuth steps of the bearings the stem's `sector` covers and nearer
// than its farthest return (what may stand in front of it; the rest cannot occlude it); with
// `beyond`, those farther than its nearest return instead (what may be seen through it).
// `slack` (m) moves the farthest range out.
Points3 returnsAround(const Sector &sector, const Points3 &pts, const AzimuthColumns &cols,
                      bool beyond = false, double slack = 0.0) {
    if (sector.empty || cols.count() == 0) return Points3(0, 3);
    double far2 = beyond ? sector.near2 : sector.far2;
    if (slack > 0) far2 = std::pow(std::sqrt(far2) + slack, 2);
    const double bearing = sector.bearing, lo = sector.lo, hi = sector.hi;
    std::vector<int> rows;
    const int n = cols.count();
    const int first = cols.of(bearing + lo) - 2,
              count = static_cast<int>((hi - lo) / cols.step) + 5;
    for (int k = 0; k < std::min(count, n); ++k) {
        const size_t c = static_cast<size_t>(((first + k) % n + n) % n);
        for (int j = cols.start[c]; j < cols.start[c + 1]; ++j) {
            const int i = cols.rows[static_cast<size_t>(j)];
            const double d2 = pts(i, 0) * pts(i, 0) + pts(i, 1) * pts(i, 1);
            if (beyond ? d2 > far2 : d2 < far2) rows.push_back(i);
        }
    }
    return selectRows(pts, rows);
}

// Rows of `p` with lo <= z <= hi within `margin` of the x-y box of `box` (cheap: spares most
// stems the bearings of their returns).
Points3 rowsNearBox(const Points3 &p, const Points3 &box, double lo, double hi, double margin) {
    if (p.rows() == 0 || box.rows() == 0) return Points3(0, 3);
    const Eigen::Array2d mn = box.leftCols<2>().colwise().minCoeff().array() - margin,
                         mx = box.leftCols<2>().colwise().maxCoeff().array() + margin;
    std::vector<int> rows;
    for (Eigen::Index i = 0; i < p.rows(); ++i)
        if (p(i, 2) >= lo && p(i, 2) <= hi && p(i, 0) >= mn(0) && p(i, 0) <= mx(0) &&
            p(i, 1) >= mn(1) && p(i, 1) <= mx(1))
            rows.push_back(static_cast<int>(i));
    return selectRows(p, rows);
}

// A stem's view with, near breast height (`lo`..`hi`), every non-ground return of the scan on
// its surface (see onStemSurface) instead of its own when the intensity filter removed some
// there (`bright`): the filter may have taken most of a bright stem, and the clustering then
// the rest of its section. The span is the section's when it holds >= 4 of the stem's returns,
// else the whole stem's.
Points3 withReturnsOnSurface(const Points3 &view, const Points3 &pts, const AzimuthColumns &columns,
                             const Points3 &bright, const SilhouetteSensor &sensor, double lo,
                             double hi) {
    if (view.rows() < 2) return view;
    const Points3 b = rowsNearBox(bright, view, lo, hi, 0.15);
    if (b.rows() == 0) return view;
    std::vector<int> in_section, outside;
    for (Eigen::Index i = 0; i < view.rows(); ++i)
        (view(i, 2) >= lo && view(i, 2) <= hi ? in_section : outside)
            .push_back(static_cast<int>(i));
    const Points3 section = selectRows(view, in_section);
    const Points3 &span = section.rows() >= 4 ? section : view;
    // Fewer than 2 returns the filter removed lie on the stem (no scan line's worth): its view is
    // whole, and most stems cost no more.
    if (onStemSurface(span, b, sensor).size() < 2) return view;
    const Points3 o =
        rowsAtHeights(returnsAround(sectorOf(span), pts, columns, false, 0.15), lo, hi);
    Points3 cand(b.rows() + o.rows(), 3);
    cand << b, o;
    const std::vector<int> on = onStemSurface(span, cand, sensor);
    if (on.size() < in_section.size()) return view;
    Points3 out(static_cast<Eigen::Index>(outside.size() + on.size()), 3);
    out << selectRows(view, outside), selectRows(cand, on);
    return out;
}

// 6. Per stem: shape, local ground, breast-height centre and diameter.
// `pts`: the input's returns, those the intensity filter removed (`bright`) appended after
// the first `kept_rows` when the clustering saw them.
void measureStems(const Points3 &pts, Eigen::Index kept_rows, const Points3 &bright,
                  const Points3 &filtered, const NormalFilterResult &nf, const Clusters &stems,
                  const GroundSegmentation &gs, const SensorGeometry &sensor, bool scan_centred,
                  const PerceptionConfig &opt, Detection &det) {
    const SegmentationConfig &so = opt.segmentation;
    SilhouetteView silhouette;
    silhouette.sensor = silhouetteSensor(sensor);
    DiameterConfig dopt = opt.diameter;
    if (!scan_centred)
        dopt.min_arc_coverage = std::max(dopt.min_arc_coverage, dopt.map_min_arc_coverage);
    const bool use_silhouette = opt.diameter.silhouette && scan_centred && sensor.has_range_image &&
                                !silhouette.sensor.vertical_angles_rad.empty();
    const std::vector<Points3> seen =
        use_silhouette ? fullResolutionStems(pts, gs, nf, stems, kept_rows, opt.filter.voxel_m)
                       : std::vector<Points3>(stems.size());
    const double step = silhouette.sensor.azimuth_step_rad;
    // Occluders, returns seen through a stem and those given back (withReturnsOnSurface) come
    // from the kept returns, the removed ones from `bright`.
    std::vector<char> skip = gs.is_ground;
    for (size_t i = static_cast<size_t>(kept_rows); i < skip.size(); ++i) skip[i] = 1;
    const AzimuthColumns columns =
        use_silhouette ? azimuthColumns(pts, &skip, step) : AzimuthColumns{};
    // The thinned ground too: beams passing between two stems of a cluster often end there.
    const AzimuthColumns ground_columns =
        use_silhouette ? azimuthColumns(det.ground, nullptr, step) : AzimuthColumns{};
    const Eigen::Vector3d sensor_origin = Eigen::Vector3d::Zero();
    const GroundByX ground_by_x = groundByX(det.ground);
    for (size_t k = 0; k < stems.size(); ++k) {
        const std::vector<int> &rows = stems[k];
        Stem st;
        st.points = selectRows(filtered, rows);
        st.normals = selectRows(nf.normals, rows);
        st.shape = clusterShape(filtered, rows, det.up);
        if (!isStem(st.shape, static_cast<int>(rows.size()), so)) continue;  // merged oddly
        double base = stemGroundHeight(det, ground_by_x, gs, st.shape.mean.head<2>(), so);
        st.ground_found = std::isfinite(base);
        if (std::isfinite(opt.breast_height_z)) {
            // A stem without points near the given height has no DBH there (the cylinder
            // fallback would give one from points metres away): no stem.
            if (!reachesHeight(st.points, opt.breast_height_z, opt.diameter.band_max_half_m))
                continue;
            base = opt.breast_height_z - bandMiddle(opt.diameter);
            st.breast_source = BreastHeightSource::Explicit;
        } else if (!st.ground_found) {
            base = st.points.col(2).minCoeff();
            st.breast_source = BreastHeightSource::LowestPoint;
        }
        st.base_z = base;
        const Points3 &view = seen[k].rows() > 0 ? seen[k] : st.points;
        const double mid = base + bandMiddle(opt.diameter);
        silhouette.points = withReturnsOnSurface(view, pts, columns, bright, silhouette.sensor,
                                                 mid - opt.diameter.band_max_half_m,
                                                 mid + opt.diameter.band_max_half_m);
        const Sector sector = sectorOf(view);
        silhouette.occluders = returnsAround(sector, pts, columns);
        const Points3 beyond = returnsAround(sector, pts, columns, true),
                      beyond_ground = returnsAround(sector, det.ground, ground_columns, true);
        silhouette.beyond.resize(beyond.rows() + beyond_ground.rows(), 3);
        silhouette.beyond << beyond, beyond_ground;
        st.diameter = estimateDiameter(st.points, st.normals, base, det.up, dopt,
                                       use_silhouette ? &silhouette : nullptr,
                                       scan_centred ? &sensor_origin : nullptr);
        if (st.diameter.centre.allFinite()) {
            st.breast = st.diameter.centre;
        } else {
            // No accepted fit: the principal axis at breast height.
            const double zb = base + bandMiddle(opt.diameter);
            const Eigen::Vector3d &a = st.shape.axis;
            st.breast = st.shape.mean + a * ((zb - st.shape.mean.z()) / std::max(a.z(), 0.2));
        }
        det.stems.push_back(std::move(st));
    }
}

// 7. Ids, and every output back from the local origin to the input frame.
void toInputFrame(const Eigen::RowVector3d &origin, Detection &det) {
    for (size_t k = 0; k < det.stems.size(); ++k) {
        Stem &st = det.stems[k];
        st.id = static_cast<int>(k);
        if (origin.isZero()) continue;
        st.points.rowwise() += origin;
        st.shape.mean += origin.transpose();
        st.breast += origin.transpose();
        st.base_z += origin.z();
        st.diameter.centre += origin.transpose();
        st.diameter.circle.centre += origin.transpose();
        st.diameter.cylinder.centre += origin.transpose();
    }
    if (!origin.isZero()) det.ground.rowwise() += origin;
}

}  // namespace

Detection detectStems(const Eigen::Ref<const Points3> &points,
                      const Eigen::Ref<const Eigen::VectorXd> &intensity,
                      const Eigen::Ref<const Eigen::VectorXi> &ring, const SensorGeometry &sensor,
                      bool scan_centred, const PerceptionConfig &opt) {
    requirePerPoint("detectStems", "intensities", intensity.size(), points.rows(), true);
    requirePerPoint("detectStems", "rings", ring.size(), points.rows(), true);
    // PCL reports every RANSAC without a model on stderr; a stem without a cylinder is normal.
    pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS);
    Detection det;
    det.input_points = static_cast<int>(points.rows());
    StageClock clock;
    const auto t0 = clock.wall;
    const double c0 = clock.cpu;

    Input in = selectInput(points, intensity, ring, scan_centred, opt, det);
    clock.lap(det, "intensity");
    GroundSegmentation gs = findGround(in.pts, scan_centred, opt, det);
    if (intensityAsEvidence(in, sensor, scan_centred, opt))
        appendRemovedReturns(in, gs, opt.ground.cell_height_m);
    clock.lap(det, "ground");
    const NormalFilterResult nf =
        filterStemPoints(in.pts, in.kept_rows, gs, sensor, scan_centred, opt);
    const Points3 filtered = selectRows(in.pts, nf.kept);
    det.filtered_points = static_cast<int>(filtered.rows());
    clock.lap(det, "normals");
    // The first nf.own_rows filtered rows are the kept returns that pass as without the removed
    // ones: clustered alone, they give the stems found without them; the removed returns can
    // only add evidence pieces (withEvidencePieces).
    const auto own = static_cast<Eigen::Index>(nf.own_rows);
    const bool evidence = own < filtered.rows();
    const Points3 own_filtered = evidence ? Points3(filtered.topRows(own)) : Points3(0, 3);
    const Points3 &kept_filtered = evidence ? own_filtered : filtered;
    const Clusters coarse =
        coarseClusters(kept_filtered, nf, in.ring, sensor, scan_centred, opt.segmentation);
    det.coarse_clusters = static_cast<int>(coarse.size());
    clock.lap(det, "clustering");
    Clusters pieces =
        stemPieces(kept_filtered, coarse, sensor, scan_centred, opt.segmentation, det);
    if (evidence)
        pieces = withEvidencePieces(filtered, nf, in.ring, in.kept_rows, sensor, opt.segmentation,
                                    det.up, std::move(pieces));
    const Clusters stems = mergeStemClusters(filtered, pieces, opt.segmentation);
    clock.lap(det, "classification");
    measureStems(in.pts, in.kept_rows, in.bright, filtered, nf, stems, gs, sensor, scan_centred,
                 opt, det);
    if (!scan_centred && det.stems.empty()) det.stems = groundlessStems(in.pts, opt);
    toInputFrame(in.origin, det);
    clock.lap(det, "diameter");
    det.timing_ms["total"] = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    det.cpu_ms["total"] = threadCpuMs() - c0;
    return det;
}

}  // namespace forestslam::perception
