#include "forestslam/perception/stems.hpp"

#include <pcl/ModelCoefficients.h>
#include <pcl/point_types.h>
#include <pcl/sample_consensus/method_types.h>
#include <pcl/sample_consensus/model_types.h>
#include <pcl/segmentation/sac_segmentation.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>

#include "forestslam/common/circle_fit.hpp"
#include "forestslam/common/median.hpp"

namespace forestslam::perception {
namespace {

// Quality of a circle (centre on an axis through `centre` along `axis`, radius r) on `band`.
void evaluate(const Eigen::Ref<const Points3> &band, const DiameterConfig &opt, DiameterFit &f) {
    const Eigen::Vector3d a = f.axis.normalized();
    Eigen::Vector3d u = a.unitOrthogonal(), v = a.cross(u);
    Points2 plane(band.rows(), 2);
    double ss = 0;
    std::vector<int> in;
    for (Eigen::Index i = 0; i < band.rows(); ++i) {
        const Eigen::Vector3d d = band.row(i).transpose() - f.centre;
        const Eigen::Vector3d radial = d - d.dot(a) * a;
        plane.row(i) << radial.dot(u), radial.dot(v);
        const double e = radial.norm() - f.radius;
        if (std::abs(e) <= opt.inlier_threshold_m) {
            in.push_back(static_cast<int>(i));
            ss += e * e;
        }
    }
    f.inliers = static_cast<int>(in.size());
    f.rms_m = in.empty() ? kNaN : std::sqrt(ss / static_cast<double>(in.size()));
    // Covariance of (centre, radius) of the circle on its inliers, rms^2 (J^T J)^-1: large on
    // short arcs, where centre and radius trade off. The circle was fitted to other points (the
    // whole band, or a cylinder by SAC), so the residual variance takes no fitted parameters
    // (and no floor: the fits' quality scores see their RMS as it is).
    const double var_r =
        circleCovariance(plane, in, Eigen::Vector2d::Zero(), f.radius, 0, 0.0)(2, 2);
    if (std::isfinite(var_r)) f.radius_std = std::sqrt(std::max(0.0, var_r));
    f.arc_coverage = arcCoverage(plane, in, Eigen::Vector2d::Zero(), 36);
    const double ratio = band.rows() > 0 ? static_cast<double>(in.size()) / band.rows() : 0.0;
    f.score = in.empty() ? 0.0 : ratio * f.arc_coverage / std::max(f.rms_m, 0.005);
    f.valid = f.valid && f.inliers >= 3 && f.arc_coverage >= opt.min_arc_coverage &&
              f.radius >= opt.min_radius_m && f.radius <= opt.max_radius_m;
}

Points3 rowsBetween(const Eigen::Ref<const Points3> &p, double lo, double hi,
                    std::vector<int> *rows_out = nullptr) {
    std::vector<int> rows;
    for (Eigen::Index i = 0; i < p.rows(); ++i)
        if (p(i, 2) >= lo && p(i, 2) <= hi) rows.push_back(static_cast<int>(i));
    if (rows_out) *rows_out = rows;
    return selectRows(p, rows);
}

}  // namespace

ClusterShape clusterShape(const Eigen::Ref<const Points3> &points, const std::vector<int> &rows,
                          const Eigen::Vector3d &up) {
    ClusterShape s;
    const size_t n = rows.size();
    if (n == 0) return s;
    for (int i : rows) s.mean += points.row(i).transpose();
    s.mean /= static_cast<double>(n);
    for (int i : rows) {
        const Eigen::Vector3d d = points.row(i).transpose() - s.mean;
        s.cov += d * d.transpose();
    }
    s.cov /= static_cast<double>(std::max<size_t>(1, n - 1));
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(s.cov);
    const Eigen::Vector3d ev = eig.eigenvalues().cwiseMax(0.0);  // ascending
    s.singular << std::sqrt(ev(2)), std::sqrt(ev(1)), std::sqrt(ev(0));
    s.axis = eig.eigenvectors().col(2);
    if (s.axis.dot(up) < 0) s.axis = -s.axis;
    const Eigen::Vector3d second = eig.eigenvectors().col(1);
    double lo = 1e300, hi = -1e300, wlo = 1e300, whi = -1e300;
    for (int i : rows) {
        const Eigen::Vector3d d = points.row(i).transpose() - s.mean;
        lo = std::min(lo, d.dot(s.axis)), hi = std::max(hi, d.dot(s.axis));
        wlo = std::min(wlo, d.dot(second)), whi = std::max(whi, d.dot(second));
    }
    s.length = hi - lo;
    s.width = whi - wlo;
    s.axis_angle = std::acos(std::clamp(s.axis.dot(up.normalized()), -1.0, 1.0));
    return s;
}

bool isStem(const ClusterShape &s, int count, const SegmentationConfig &o) {
    return count >= o.min_points && s.length >= o.min_length_m &&
           s.axis_angle <= o.max_axis_angle_rad && s.width <= o.max_width_m &&
           s.singular(0) >= o.min_sv_ratio * std::max(s.singular(1), 1e-9);
}

Clusters mergeStemClusters(const Eigen::Ref<const Points3> &points, const Clusters &stems,
                           const SegmentationConfig &o) {
    const size_t n = stems.size();
    std::vector<Eigen::Vector2d> xy(n, Eigen::Vector2d::Zero());
    for (size_t k = 0; k < n; ++k) {
        for (int i : stems[k]) xy[k] += points.block<1, 2>(i, 0).transpose();
        xy[k] /= static_cast<double>(std::max<size_t>(1, stems[k].size()));
    }
    std::vector<int> parent(n);
    std::iota(parent.begin(), parent.end(), 0);
    auto find = [&](int a) {
        while (parent[a] != a) a = parent[a] = parent[parent[a]];
        return a;
    };
    for (size_t a = 0; a < n; ++a)
        for (size_t b = a + 1; b < n; ++b)
            if ((xy[a] - xy[b]).norm() < o.merge_xy_m)
                parent[find(static_cast<int>(a))] = find(static_cast<int>(b));
    std::vector<std::vector<int>> groups(n);
    for (size_t k = 0; k < n; ++k) {
        auto &g = groups[static_cast<size_t>(find(static_cast<int>(k)))];
        g.insert(g.end(), stems[k].begin(), stems[k].end());
    }
    Clusters out;
    for (auto &g : groups)
        if (!g.empty()) out.push_back(std::move(g));
    return out;
}

double localGroundHeight(const Eigen::Ref<const Points3> &ground, const Eigen::Vector2d &xy,
                         double radius) {
    std::vector<double> z;
    const double r2 = radius * radius;
    for (Eigen::Index i = 0; i < ground.rows(); ++i) {
        const double dx = ground(i, 0) - xy.x(), dy = ground(i, 1) - xy.y();
        if (dx * dx + dy * dy <= r2) z.push_back(ground(i, 2));
    }
    return median(std::move(z));
}

GroundByX groundByX(const Eigen::Ref<const Points3> &ground) {
    GroundByX g;
    g.p.reserve(static_cast<size_t>(ground.rows()));
    for (Eigen::Index i = 0; i < ground.rows(); ++i)
        if (std::isfinite(ground(i, 0)) && std::isfinite(ground(i, 1)))
            g.p.push_back(ground.row(i).transpose());
    std::sort(g.p.begin(), g.p.end(),
              [](const Eigen::Vector3d &a, const Eigen::Vector3d &b) { return a.x() < b.x(); });
    return g;
}

// The strip is padded by 1e-6 m so that rounding in dx * dx + dy * dy cannot leave out a return
// the test accepts; the median does not depend on the order the returns are found in.
double localGroundHeight(const GroundByX &g, const Eigen::Vector2d &xy, double radius) {
    std::vector<double> z;
    const double r2 = radius * radius, lo = xy.x() - radius - 1e-6, hi = xy.x() + radius + 1e-6;
    auto it = std::lower_bound(g.p.begin(), g.p.end(), lo,
                               [](const Eigen::Vector3d &a, double x) { return a.x() < x; });
    for (; it != g.p.end() && it->x() <= hi; ++it) {
        const double dx = it->x() - xy.x(), dy = it->y() - xy.y();
        if (dx * dx + dy * dy <= r2) z.push_back(it->z());
    }
    return median(std::move(z));
}

double planeGroundHeight(const Eigen::Ref<const Points3> &ground, const Eigen::Vector2d &xy,
                         double radius) {
    std::vector<int> rows;
    for (Eigen::Index i = 0; i < ground.rows(); ++i)
        if ((ground.block<1, 2>(i, 0).transpose() - xy).norm() <= radius)
            rows.push_back(static_cast<int>(i));
    Eigen::Vector3d abc = Eigen::Vector3d::Constant(kNaN);
    for (int pass = 0; pass < 2; ++pass) {
        if (rows.size() < 10) return kNaN;
        Eigen::MatrixXd A(rows.size(), 3);
        Eigen::VectorXd b(rows.size());
        for (size_t k = 0; k < rows.size(); ++k) {
            A.row(static_cast<Eigen::Index>(k)) << ground(rows[k], 0) - xy.x(),
                ground(rows[k], 1) - xy.y(), 1.0;
            b(static_cast<Eigen::Index>(k)) = ground(rows[k], 2);
        }
        abc = A.colPivHouseholderQr().solve(b);
        const Eigen::VectorXd res = (A * abc - b).cwiseAbs();
        std::vector<double> sorted(res.data(), res.data() + res.size());
        const double cut = 3.0 * std::max(median(sorted), 0.02);
        std::vector<int> keep;
        for (size_t k = 0; k < rows.size(); ++k)
            if (res(static_cast<Eigen::Index>(k)) <= cut) keep.push_back(rows[k]);
        rows.swap(keep);
    }
    return abc(2);
}

namespace {

// Horizontal bearing and range of each row of a section, computed once for the silhouette's
// stages (scan lines, line extents, centre distance).
struct Polar {
    std::vector<double> az, rho;
};

Polar polar(const Eigen::Ref<const Points3> &p) {
    Polar pl;
    pl.az.resize(static_cast<size_t>(p.rows()));
    pl.rho.resize(static_cast<size_t>(p.rows()));
    for (Eigen::Index i = 0; i < p.rows(); ++i) {
        pl.az[static_cast<size_t>(i)] = std::atan2(p(i, 1), p(i, 0));
        pl.rho[static_cast<size_t>(i)] = std::hypot(p(i, 0), p(i, 1));
    }
    return pl;
}

// Distance from the sensor to the centre of a stem of radius r seen at azimuth az. A point at
// range rho, azimuth offset a from az, lies r from the centre (D, 0) of the bearing frame, so
// D = rho cos a + sqrt(r^2 - (rho sin a)^2). The median over the points facing the sensor
// (lateral offset <= r/2, where the root is well conditioned) is unbiased under range noise;
// the nearest range of the section, used before, is the minimum of noisy ranges and put stem
// centres 3-4 cm (median) toward a VLP-16. `fallback` when no point qualifies.
double centreDistance(const Polar &pl, double az, double r, double fallback) {
    std::vector<double> d;
    for (size_t i = 0; i < pl.rho.size(); ++i) {
        const double rho = pl.rho[i];
        double a = pl.az[i] - az;
        a = std::atan2(std::sin(a), std::cos(a));
        const double lateral = rho * std::sin(a);
        if (std::abs(lateral) <= 0.5 * r)
            d.push_back(rho * std::cos(a) + std::sqrt(r * r - lateral * lateral));
    }
    return d.size() >= 3 ? median(std::move(d)) : fallback;
}

// One scan line across a stem: its angular width (outermost returns plus one azimuth step: the
// true edge lies on average half a step beyond each), the bearing of its middle (relative to
// `bearing`) and the range of its front.
struct SilhouetteLine {
    double width = 0, mid = 0, front = kNaN;
};

// The front is the median range (along the middle bearing) of the returns facing the sensor
// (the middle half of the line, at least the return nearest the middle): the nearest range,
// used before, is the minimum of noisy ranges and lies short by about 1.5-2 range sigmas; with
// r = front sin(w/2) / (1 - sin(w/2)) that shrank near stems (-0.5 cm DBH within 6 m at 3 cm
// noise, bench/dbh_near_range.py). The facing returns lie up to 0.13 r behind the front,
// which moves r by 0.13 r^2 / front at most.
SilhouetteLine lineExtent(const Polar &pl, const std::vector<int> &rows, double bearing,
                          double step) {
    SilhouetteLine sl;
    std::vector<double> a(rows.size()), rho(rows.size());
    double lo = 1e9, hi = -1e9;
    for (size_t k = 0; k < rows.size(); ++k) {
        const size_t i = static_cast<size_t>(rows[k]);
        const double az = pl.az[i] - bearing;
        a[k] = std::atan2(std::sin(az), std::cos(az));
        rho[k] = pl.rho[i];
        lo = std::min(lo, a[k]), hi = std::max(hi, a[k]);
    }
    sl.width = hi - lo + step;
    sl.mid = 0.5 * (lo + hi);
    std::vector<double> front;
    size_t nearest = 0;
    for (size_t k = 0; k < rows.size(); ++k) {
        const double off = std::abs(a[k] - sl.mid);
        if (off <= 0.25 * (hi - lo) + 0.5 * step) front.push_back(rho[k] * std::cos(off));
        if (off < std::abs(a[nearest] - sl.mid)) nearest = k;
    }
    sl.front = front.empty() ? rho[nearest] * std::cos(a[nearest] - sl.mid) : median(front);
    return sl;
}

// Scan line of each row of `p`: the sensor's vertical angle nearest its elevation.
std::vector<int> scanLines(const Eigen::Ref<const Points3> &p, const Polar &pl,
                           const std::vector<double> &va) {
    std::vector<int> line(static_cast<size_t>(p.rows()));
    for (Eigen::Index i = 0; i < p.rows(); ++i) {
        const double el = std::atan2(p(i, 2), pl.rho[static_cast<size_t>(i)]);
        const auto it = std::lower_bound(va.begin(), va.end(), el);
        size_t k = static_cast<size_t>(it - va.begin());
        if (k == va.size() || (k > 0 && el - va[k - 1] < va[k] - el)) k = k - 1;
        line[static_cast<size_t>(i)] = static_cast<int>(k);
    }
    return line;
}

// A return near a stem: its scan line, bearing relative to the stem's and horizontal range.
struct NearbyReturn {
    int line = 0;
    double a = 0, rho = 0;
};

std::vector<NearbyReturn> nearbyReturns(const Eigen::Ref<const Points3> &p, const Polar &pl,
                                        const std::vector<double> &va, double bearing) {
    const std::vector<int> line = scanLines(p, pl, va);
    std::vector<NearbyReturn> out(line.size());
    for (size_t i = 0; i < line.size(); ++i) {
        NearbyReturn &o = out[i];
        const double a = pl.az[i] - bearing;
        o.line = line[i];
        o.a = std::atan2(std::sin(a), std::cos(a));
        o.rho = pl.rho[i];
    }
    return out;
}

std::vector<NearbyReturn> nearbyReturns(const Eigen::Ref<const Points3> &p,
                                        const std::vector<double> &va, double bearing) {
    return nearbyReturns(p, polar(p), va, bearing);
}

// Rows of `p` on the scan lines first..last (by elevation, half a line spacing of margin):
// the returns that can lie on a silhouette's lines, found before any atan2 (speed).
Points3 onLines(const Eigen::Ref<const Points3> &p, const std::vector<double> &va, int first,
                int last) {
    const size_t f = static_cast<size_t>(first), l = static_cast<size_t>(last);
    const double lo = std::tan(f > 0 ? 0.5 * (va[f - 1] + va[f]) : va[f] - 0.1);
    const double hi = std::tan(l + 1 < va.size() ? 0.5 * (va[l] + va[l + 1]) : va[l] + 0.1);
    std::vector<int> rows;
    for (Eigen::Index i = 0; i < p.rows(); ++i) {
        const double rho = std::hypot(p(i, 0), p(i, 1));
        if (p(i, 2) >= lo * rho && p(i, 2) <= hi * rho) rows.push_back(static_cast<int>(i));
    }
    return selectRows(p, rows);
}

// A return this much nearer or farther than a surface is not on it (several range sigmas of a
// VLP-16 / HDL-32, 2-3 cm, plus bark relief).
constexpr double kBehindFrontM = 0.15;

// True when one of `occluders` on scan line `line` lies within 1.5 azimuth steps beyond either
// edge of `sl` and more than 0.15 m (several range sigmas) nearer than its front.
bool edgeOccluded(const SilhouetteLine &sl, int line, const std::vector<NearbyReturn> &occluders,
                  double step) {
    const double lo = sl.mid - 0.5 * (sl.width - step), hi = sl.mid + 0.5 * (sl.width - step);
    for (const NearbyReturn &o : occluders) {
        if (o.line != line || !(o.rho < sl.front - kBehindFrontM)) continue;
        if ((o.a < lo && o.a >= lo - 1.5 * step) || (o.a > hi && o.a <= hi + 1.5 * step))
            return true;
    }
    return false;
}

// True when one of `returns` on scan line `line` lies within 1.5 azimuth steps beyond either
// edge of `sl` at the depth of its front (within 0.15 m): the surface goes on beyond the edge,
// so the line spans a strip of something wider (a stem the normal filter or the clustering
// cut), not a whole stem. The beams beside a real edge pass the stem.
bool edgeContinues(const SilhouetteLine &sl, int line, const std::vector<NearbyReturn> &returns,
                   double step) {
    // The next beams beyond the outermost returns: from half a step (the line's own returns,
    // up to rounding, lie within) to 1.5 steps out.
    const double lo = sl.mid - 0.5 * sl.width, hi = sl.mid + 0.5 * sl.width;
    for (const NearbyReturn &o : returns) {
        if (o.line != line || !(std::abs(o.rho - sl.front) <= kBehindFrontM)) continue;
        if ((o.a < lo && o.a >= lo - step) || (o.a > hi && o.a <= hi + step)) return true;
    }
    return false;
}

// Returns of one scan line that lie behind the front surface of the stem its width implies.
// A single stem of radius r (r = front sin(w/2) / (1 - sin(w/2)), its centre r beyond the front
// on the middle bearing) stops every beam that meets it: no return of its own lies behind that
// surface. A line across two stems (a cluster that merged neighbours) spans both, and the
// farther stem's returns lie 10-50 cm behind the surface of the wide circle (VLP-16 loops:
// silhouettes of 40-80 cm on 20 + 34 cm stems). Each return is compared at its bearing moved
// half an azimuth step toward the edge (where the surface is steepest, the edge's true bearing
// is unknown within a step), so edge returns and their mixed ranges are never counted; the
// depth test is independent of which returns the intensity filter removed.
int returnsBehindFront(const std::vector<NearbyReturn> &returns, int line, const SilhouetteLine &sl,
                       double step) {
    const double s = std::sin(0.5 * sl.width);
    const double r = sl.front * s / (1.0 - s), centre = sl.front + r;
    int behind = 0;
    for (const NearbyReturn &o : returns) {
        if (o.line != line) continue;
        const double a = o.a - sl.mid;
        const double off = std::abs(std::atan2(std::sin(a), std::cos(a))) + 0.5 * step;
        const double lateral = centre * std::sin(off);
        if (!(lateral < r)) continue;
        const double surface = centre * std::cos(off) - std::sqrt(r * r - lateral * lateral);
        if (o.rho > surface + kBehindFrontM) ++behind;
    }
    return behind;
}

// Extent of a stem's returns on one scan line: bearings (relative to the stem's) and ranges.
struct LineSpan {
    int count = 0;
    double lo = 1e9, hi = -1e9, near = 1e9, far = -1e9;
    void add(double a, double rho) {
        ++count;
        lo = std::min(lo, a), hi = std::max(hi, a);
        near = std::min(near, rho), far = std::max(far, rho);
    }
    void add(const LineSpan &o) {
        count += o.count;
        lo = std::min(lo, o.lo), hi = std::max(hi, o.hi);
        near = std::min(near, o.near), far = std::max(far, o.far);
    }
    bool holds(double a, double rho) const {
        return count >= 2 && a >= lo && a <= hi && rho >= near - kBehindFrontM &&
               rho <= far + kBehindFrontM;
    }
};

}  // namespace

std::vector<int> onStemSurface(const Eigen::Ref<const Points3> &stem,
                               const Eigen::Ref<const Points3> &candidates,
                               const SilhouetteSensor &sensor) {
    std::vector<int> out;
    const auto &va = sensor.vertical_angles_rad;
    if (stem.rows() < 2 || va.empty()) return out;
    const Eigen::Vector2d m = stem.leftCols<2>().colwise().mean().transpose();
    const double bearing = std::atan2(m.y(), m.x());
    LineSpan span;
    for (const NearbyReturn &r : nearbyReturns(stem, va, bearing)) span.add(r.a, r.rho);
    // Each edge lies up to one azimuth step beyond the outermost returns seen.
    span.lo -= sensor.azimuth_step_rad, span.hi += sensor.azimuth_step_rad;
    const std::vector<NearbyReturn> c = nearbyReturns(candidates, va, bearing);
    for (size_t i = 0; i < c.size(); ++i)
        if (span.holds(c[i].a, c[i].rho)) out.push_back(static_cast<int>(i));
    return out;
}

namespace {

// Silhouette radius from the scan lines of the stem section `p` (see StemDiameter); lines cut
// by something in front of the stem (`occluders`) and lines across more than one object (two
// or more returns behind the front of the stem their width implies) are left out. `pl` and
// `po`: polar(p) and polar(occluders), shared with seenWidth.
DiameterFit silhouetteFit(const Eigen::Ref<const Points3> &p, const Polar &pl,
                          const Eigen::Ref<const Points3> &occluders, const Polar &po,
                          const Eigen::Ref<const Points3> &beyond, double mid_z,
                          const SilhouetteSensor &sensor, const DiameterConfig &opt) {
    DiameterFit f;
    const auto &va = sensor.vertical_angles_rad;
    if (p.rows() < 4 || va.empty() || !(sensor.azimuth_step_rad > 0)) return f;
    Eigen::Vector2d m = p.leftCols<2>().colwise().mean().transpose();
    const double bearing = std::atan2(m.y(), m.x());
    std::map<int, std::vector<int>> lines;
    const std::vector<int> line_of = scanLines(p, pl, va);
    for (Eigen::Index i = 0; i < p.rows(); ++i)
        lines[line_of[static_cast<size_t>(i)]].push_back(static_cast<int>(i));
    const std::vector<NearbyReturn> nearby = nearbyReturns(occluders, po, va, bearing);
    const std::vector<NearbyReturn> seen_through =
        beyond.rows() > 0
            ? nearbyReturns(onLines(beyond, va, lines.begin()->first, lines.rbegin()->first), va,
                            bearing)
            : nearbyReturns(p, pl, va, bearing);
    std::vector<double> radii, mids, dists;
    int strips = 0;  // kept lines whose surface goes on beyond an edge (see edgeContinues)
    for (const auto &[line, rows] : lines) {
        if (rows.size() < 2) continue;
        const SilhouetteLine sl = lineExtent(pl, rows, bearing, sensor.azimuth_step_rad);
        const double s = std::sin(0.5 * sl.width);
        if (!(s > 0 && s < 0.9)) continue;
        if (edgeOccluded(sl, line, nearby, sensor.azimuth_step_rad)) continue;
        if (returnsBehindFront(seen_through, line, sl, sensor.azimuth_step_rad) >= 2) {
            ++f.multi_object_lines;
            continue;
        }
        const double step = sensor.azimuth_step_rad;
        strips +=
            edgeContinues(sl, line, nearby, step) || edgeContinues(sl, line, seen_through, step);
        radii.push_back(sl.front * s / (1.0 - s));
        mids.push_back(sl.mid);
        dists.push_back(sl.front);
    }
    // Most lines across several objects: a cluster of neighbouring stems, whose remaining
    // lines are no one stem's width either.
    f.inliers = static_cast<int>(radii.size());
    if (radii.size() < 2 || f.multi_object_lines >= static_cast<int>(radii.size())) return f;
    const double r = median(radii);
    std::vector<double> dev;
    for (double x : radii) dev.push_back(std::abs(x - r));
    const double spread = 1.4826 * median(dev);
    const double az = bearing + median(mids);
    const double d = centreDistance(pl, az, r, median(dists) + r);
    f.radius = r;
    f.centre = Eigen::Vector3d(d * std::cos(az), d * std::sin(az), mid_z);
    f.rms_m = spread;
    f.arc_coverage = 0.0;
    f.score = static_cast<double>(radii.size()) / std::max(spread, 0.005);
    // Expected DBH error: angular sampling (range * step / sqrt(6), shared by all lines) and
    // the standard error of the median of the lines' radii (1.25 spread / sqrt(n), x2).
    const double sampling = d * sensor.azimuth_step_rad / std::sqrt(6.0);
    const double median_se = 2.0 * 1.2533 * spread / std::sqrt(static_cast<double>(radii.size()));
    f.radius_std = 0.5 * std::hypot(sampling, median_se);
    // Below the circle fits' radius floor (their fits of a few noisy points of a thin stem are
    // noise) a silhouette still measures: each line kept spans >= 2 returns, so the stem is
    // resolved at this range (whether well enough is the tree map's decision over all its
    // scans: its range gate). Saplings of 2-5 cm are trees. Such a narrow silhouette counts
    // only when most of its lines end at real edges: a strip of a wider stem is no DBH.
    const bool thin_ok = 2 * strips < static_cast<int>(radii.size());
    f.valid = spread <= std::max(0.02, 0.25 * r) && r <= opt.max_radius_m &&
              (r >= opt.min_radius_m || thin_ok);
    return f;
}

}  // namespace

namespace {

// Breast-height band, widened symmetrically around 1.3 m while it holds too few points (a
// VLP-16 at 10 m has one ring per 0.35 m).
Points3 breastHeightBand(const Eigen::Ref<const Points3> &points, double mid,
                         const DiameterConfig &opt) {
    double half = 0.5 * (opt.band_high_m - opt.band_low_m);
    Points3 band = rowsBetween(points, mid - half, mid + half);
    while (band.rows() < opt.min_band_points && half < opt.band_max_half_m) {
        half = std::min(opt.band_max_half_m, half + 0.1);
        band = rowsBetween(points, mid - half, mid + half);
    }
    return band;
}

// Robust circle fit of the band in the horizontal plane (under range noise along the beams
// when every point was seen from `view_origin`).
DiameterFit bandCircle(const Points3 &band, double mid, const DiameterConfig &opt,
                       const Eigen::Vector3d *view_origin) {
    DiameterFit f;
    if (band.rows() < 3) return f;
    CircleFitConfig co;
    co.inlier_threshold_m = opt.inlier_threshold_m;
    co.min_radius_m = opt.min_radius_m;
    co.max_radius_m = opt.max_radius_m;
    const Points2 xy = band.leftCols<2>();
    CircleFit cf;
    if (view_origin != nullptr) {
        const Points2 origins = view_origin->head<2>().transpose().replicate(xy.rows(), 1);
        cf = fitCircleRays(xy, origins, co);
    } else {
        cf = fitCircle(xy, co);
    }
    if (!cf.valid) return f;
    f.valid = true;
    f.radius = cf.radius;
    f.centre << cf.centre.x(), cf.centre.y(), mid;
    f.axis = Eigen::Vector3d::UnitZ();
    evaluate(band, opt, f);
    return f;
}

// Rows of the lower stem section for the SAC cylinder (all rows when it holds fewer than 8).
std::vector<int> cylinderSection(const Eigen::Ref<const Points3> &points, double base_z,
                                 const DiameterConfig &opt) {
    std::vector<int> rows;
    rowsBetween(points, base_z + opt.cylinder_section_low_m, base_z + opt.cylinder_section_high_m,
                &rows);
    if (rows.size() < 8) {
        rows.resize(static_cast<size_t>(points.rows()));
        std::iota(rows.begin(), rows.end(), 0);
    }
    return rows;
}

// `rows` evenly thinned to at most `cap` (0: no cap).
std::vector<int> evenlyThinned(const std::vector<int> &rows, int cap) {
    if (cap <= 0 || static_cast<int>(rows.size()) <= cap) return rows;
    std::vector<int> thin;
    const double step = static_cast<double>(rows.size()) / cap;
    for (int k = 0; k < cap; ++k) thin.push_back(rows[static_cast<size_t>(k * step)]);
    return thin;
}

// PCL SAC cylinder (with normals) on the lower stem section, its axis within max_lean_rad of
// `up`; evaluated on the band (or the section when the band holds fewer than 3 points).
DiameterFit sacCylinder(const Eigen::Ref<const Points3> &points,
                        const Eigen::Ref<const Points3> &normals, double base_z, double mid,
                        const Eigen::Vector3d &axis_up, const Points3 &band,
                        const DiameterConfig &opt) {
    DiameterFit f;
    const std::vector<int> section = cylinderSection(points, base_z, opt);
    const std::vector<int> rows = evenlyThinned(section, opt.cylinder_max_points);
    pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
    pcl::PointCloud<pcl::Normal>::Ptr cn(new pcl::PointCloud<pcl::Normal>);
    for (int i : rows) {
        cloud->push_back(pcl::PointXYZ(static_cast<float>(points(i, 0)),
                                       static_cast<float>(points(i, 1)),
                                       static_cast<float>(points(i, 2))));
        cn->push_back(pcl::Normal(static_cast<float>(normals(i, 0)),
                                  static_cast<float>(normals(i, 1)),
                                  static_cast<float>(normals(i, 2))));
    }
    pcl::SACSegmentationFromNormals<pcl::PointXYZ, pcl::Normal> seg;
    seg.setOptimizeCoefficients(true);
    seg.setModelType(pcl::SACMODEL_CYLINDER);
    seg.setMethodType(pcl::SAC_RANSAC);
    seg.setNormalDistanceWeight(opt.cylinder_normal_weight);
    seg.setMaxIterations(opt.cylinder_iterations);
    seg.setDistanceThreshold(opt.inlier_threshold_m);
    seg.setRadiusLimits(opt.min_radius_m, opt.max_radius_m);
    seg.setAxis(axis_up.cast<float>());
    seg.setEpsAngle(opt.max_lean_rad);
    seg.setInputCloud(cloud);
    seg.setInputNormals(cn);
    pcl::PointIndices inl;
    pcl::ModelCoefficients coef;
    seg.segment(inl, coef);
    if (coef.values.size() != 7 || inl.indices.size() < 3) return f;
    const Eigen::Vector3d p0(coef.values[0], coef.values[1], coef.values[2]);
    Eigen::Vector3d a(coef.values[3], coef.values[4], coef.values[5]);
    if (!(a.norm() > 0 && std::abs(a.normalized().dot(axis_up)) > 1e-3)) return f;
    a.normalize();
    if (a.dot(axis_up) < 0) a = -a;
    f.valid = true;
    f.axis = a;
    f.radius = coef.values[6];
    f.centre = p0 + a * ((mid - p0.z()) / a.z());  // axis at breast height
    evaluate(band.rows() >= 3 ? band : selectRows(points, section), opt, f);
    return f;
}

// Width (m) the section `p` spans as seen from the sensor at the origin: its angular extent
// (plus one azimuth step: each edge lies on average half a step beyond its outermost return)
// at its median range. A stem seen from outside shows its whole diameter, so no circle of it
// can be wider; a wider one is fitted to a flat fragment or a cluster of several objects
// (single VLP-16 scans: 60-110 cm circles on 14-34 cm stems of a clump). Infinite (no bound)
// with < 2 points or when one of `occluders` lies within 1.5 steps beyond either edge and
// 0.15 m nearer (the stem is partly hidden: it shows less than its diameter).
// `pl` and `po`: polar(p) and polar(occluders).
double seenWidth(const Eigen::Ref<const Points3> &p, const Polar &pl, const Polar &po,
                 double step) {
    constexpr double kNoBound = std::numeric_limits<double>::infinity();
    if (p.rows() < 2) return kNoBound;
    const Eigen::Vector2d m = p.leftCols<2>().colwise().mean().transpose();
    const double bearing = std::atan2(m.y(), m.x());
    auto offset = [bearing](double az) {
        return std::atan2(std::sin(az - bearing), std::cos(az - bearing));
    };
    double lo = 1e9, hi = -1e9;
    for (double az : pl.az) {
        const double a = offset(az);  // once: three libm calls
        lo = std::min(lo, a), hi = std::max(hi, a);
    }
    const double range = median(pl.rho);
    for (size_t i = 0; i < po.az.size(); ++i) {
        const double a = offset(po.az[i]);
        const bool at_edge = (a < lo && a >= lo - 1.5 * step) || (a > hi && a <= hi + 1.5 * step);
        if (at_edge && po.rho[i] < range - kBehindFrontM) return kNoBound;
    }
    return 2.0 * range * std::sin(0.5 * std::min(hi - lo + step, M_PI));
}

// A valid fit no wider than the section it was fitted to is seen (plus twice the inlier
// threshold: range noise at the edges); a wider one is not that stem's DBH.
bool plausible(const DiameterFit &f, double seen_width, const DiameterConfig &opt) {
    return f.valid && 2.0 * f.radius <= seen_width + 2.0 * opt.inlier_threshold_m;
}

// The band circle is the DBH definition itself; the SAC cylinder is only the fallback: on
// one-sided views its radius is off by several cm either way, far more on polygonal or rough
// stems (bench/dbh_bench.py: bias -3 cm on round, +12 to +28 cm on rough stems). An accepted
// silhouette (single scans) decides over both. In a single scan (`single_scan`) the cylinder
// gives the stem centre but no DBH: on one scan's one-sided view its DBH is 10-17 cm off (MAE;
// bench/dbh_scan_seq.py, all four loops), worse than none. Circles and cylinders wider than
// the section is seen (`seen_width`, see seenWidth) are not chosen.
void chooseDiameter(StemDiameter &out, bool single_scan, double seen_width,
                    const DiameterConfig &opt) {
    const DiameterFit *best = nullptr;
    // A view across several objects (see silhouetteFit) has no one stem's DBH: every estimate
    // spans them all (band circles as wide as the silhouette). Its centre still places the tree.
    const bool several = !out.silhouette.valid && out.silhouette.multi_object_lines > 0 &&
                         out.silhouette.multi_object_lines >= out.silhouette.inliers;
    if (plausible(out.circle, seen_width, opt))
        best = &out.circle, out.method = 1;
    else if (plausible(out.cylinder, seen_width, opt))
        best = &out.cylinder, out.method = 2;
    if (out.silhouette.valid) best = &out.silhouette, out.method = 3;
    if (best) {
        out.centre = best->centre;
        if ((single_scan && out.method == 2) || several) return;
        out.dbh = 2.0 * best->radius;
        out.dbh_std = 2.0 * best->radius_std;
    }
}

}  // namespace

StemDiameter estimateDiameter(const Eigen::Ref<const Points3> &points,
                              const Eigen::Ref<const Points3> &normals, double base_z,
                              const Eigen::Vector3d &up, const DiameterConfig &opt,
                              const SilhouetteView *silhouette,
                              const Eigen::Vector3d *view_origin) {
    requirePerPoint("estimateDiameter", "normals", normals.rows(), points.rows(), true);
    StemDiameter out;
    if (points.rows() < 3 || !std::isfinite(base_z)) return out;
    const double mid = base_z + 0.5 * (opt.band_low_m + opt.band_high_m);
    const Points3 band = breastHeightBand(points, mid, opt);
    out.band_points = static_cast<int>(band.rows());
    double seen_width = std::numeric_limits<double>::infinity();  // bound in single scans
    if (silhouette != nullptr) {
        const double lo = mid - opt.band_max_half_m, hi = mid + opt.band_max_half_m;
        const Points3 sec = silhouette->points.rows() > 0 ? rowsBetween(silhouette->points, lo, hi)
                                                          : rowsBetween(points, lo, hi);
        const Points3 occluders = rowsBetween(silhouette->occluders, lo, hi);
        const Polar psec = polar(sec), pocc = polar(occluders);  // computed once for both
        out.silhouette = silhouetteFit(sec, psec, occluders, pocc, silhouette->beyond, mid,
                                       silhouette->sensor, opt);
        const double step = silhouette->sensor.azimuth_step_rad;
        seen_width = sec.rows() >= 2 ? seenWidth(sec, psec, pocc, step)
                                     : seenWidth(band, polar(band), pocc, step);
    }
    // An accepted silhouette decides over the band circle (chooseDiameter), so the circle, a
    // third of a scan's perception, is only fitted when it may be chosen (or every estimate is
    // asked for).
    if (opt.fit_all || !out.silhouette.valid) out.circle = bandCircle(band, mid, opt, view_origin);
    // The cylinder is the costliest estimate and only the fallback: skipped when an accepted
    // silhouette or band circle decides anyway (unless every estimate is asked for).
    const bool cylinder_needed =
        opt.fit_all || !(out.silhouette.valid || plausible(out.circle, seen_width, opt));
    if (cylinder_needed && normals.rows() == points.rows() && points.rows() >= 8)
        out.cylinder = sacCylinder(points, normals, base_z, mid, up.normalized(), band, opt);
    chooseDiameter(out, silhouette != nullptr, seen_width, opt);
    return out;
}

}  // namespace forestslam::perception
