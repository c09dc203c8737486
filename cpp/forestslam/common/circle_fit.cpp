#include "forestslam/common/circle_fit.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <random>
#include <stdexcept>
#include <string>

namespace forestslam {
namespace {

constexpr double kPi = 3.14159265358979323846;

std::vector<int> finiteIndices(const Eigen::Ref<const Points2> &xy) {
    std::vector<int> rows;
    rows.reserve(static_cast<size_t>(xy.rows()));
    for (Eigen::Index i = 0; i < xy.rows(); ++i) {
        if (std::isfinite(xy(i, 0)) && std::isfinite(xy(i, 1))) rows.push_back(static_cast<int>(i));
    }
    return rows;
}

// Taubin fit (Newton on the characteristic polynomial, as in Chernov's formulation) of the
// given rows. Centred on the mean for numerical stability.
bool taubin(const Eigen::Ref<const Points2> &xy, const std::vector<int> &rows, Eigen::Vector2d &c,
            double &r) {
    const size_t n = rows.size();
    if (n < 3) return false;
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    for (int i : rows) mean += xy.row(i).transpose();
    mean /= static_cast<double>(n);
    double mxx = 0, myy = 0, mxy = 0, mxz = 0, myz = 0, mzz = 0;
    double extent = 0;
    for (int i : rows) {
        const double x = xy(i, 0) - mean.x(), y = xy(i, 1) - mean.y(), z = x * x + y * y;
        mxx += x * x;
        myy += y * y;
        mxy += x * y;
        mxz += x * z;
        myz += y * z;
        mzz += z * z;
        extent = std::max(extent, z);
    }
    const double inv = 1.0 / static_cast<double>(n);
    mxx *= inv, myy *= inv, mxy *= inv, mxz *= inv, myz *= inv, mzz *= inv;
    extent = std::sqrt(extent);
    if (!(extent > 0)) return false;
    const double mz = mxx + myy;
    const double cov_xy = mxx * myy - mxy * mxy;
    // Collinear (or nearly): the smaller eigenvalue of the scatter vanishes.
    const double tr = mxx + myy;
    const double lam_min = 0.5 * (tr - std::sqrt(std::max(0.0, tr * tr - 4.0 * cov_xy)));
    if (lam_min <= 1e-12 * tr) return false;
    const double var_z = mzz - mz * mz;
    const double a3 = 4.0 * mz;
    const double a2 = -3.0 * mz * mz - mzz;
    const double a1 = var_z * mz + 4.0 * cov_xy * mz - mxz * mxz - myz * myz;
    const double a0 =
        mxz * (mxz * myy - myz * mxy) + myz * (myz * mxx - mxz * mxy) - var_z * cov_xy;
    const double a22 = a2 + a2, a33 = a3 + a3 + a3;
    double x = 0, y = a0;
    for (int it = 0; it < 99; ++it) {
        const double dy = a1 + x * (a22 + a33 * x);
        const double xnew = x - y / dy;
        if (xnew == x || !std::isfinite(xnew)) break;
        const double ynew = a0 + xnew * (a1 + xnew * (a2 + xnew * a3));
        if (std::abs(ynew) >= std::abs(y)) break;
        x = xnew;
        y = ynew;
    }
    const double det = x * x - x * mz + cov_xy;
    if (det == 0.0) return false;
    const double cx = (mxz * (myy - x) - myz * mxy) / det / 2.0;
    const double cy = (myz * (mxx - x) - mxz * mxy) / det / 2.0;
    c = Eigen::Vector2d(cx, cy) + mean;
    r = std::sqrt(cx * cx + cy * cy + mz);
    // A radius far beyond the data's extent is a line in disguise.
    return std::isfinite(r) && std::isfinite(c.x()) && std::isfinite(c.y()) && r < 1e4 * extent;
}

bool circleFrom3(const Eigen::Vector2d &p, const Eigen::Vector2d &q, const Eigen::Vector2d &s,
                 Eigen::Vector2d &c, double &r) {
    const Eigen::Vector2d b = q - p, d = s - p;
    const double den = 2.0 * (b.x() * d.y() - b.y() * d.x());
    const double scale = b.squaredNorm() * d.squaredNorm();
    if (std::abs(den) <= 1e-9 * std::sqrt(scale) || scale == 0.0) return false;
    const double b2 = b.squaredNorm(), d2 = d.squaredNorm();
    const Eigen::Vector2d u((d.y() * b2 - b.y() * d2) / den, (b.x() * d2 - d.x() * b2) / den);
    c = p + u;
    r = u.norm();
    return std::isfinite(r);
}

double tukeyWeight(double e, double c) {
    const double u = e / c;
    if (std::abs(u) >= 1.0) return 0.0;
    const double t = 1.0 - u * u;
    return t * t;
}

// One pass of refineGeometric over the rows at (c, r): Tukey weights, normal equations and
// the weighted cost. Written exactly as the separate passes it replaces (same expressions in
// the same order), so the refinement stays bit-identical.
struct GeoLinearization {
    std::vector<double> w;
    Eigen::Matrix3d JtJ;
    Eigen::Vector3d Jte;
    double wsum, cost;
};

// Normal equations J^T W J, J^T W e of a 3-parameter fit, summed element by element in the
// order of Eigen's products (a generic 3x3 product through Eigen cost most of the refinement
// on small arcs), so the sums are bit-identical to `JtJ += w * J * J.transpose()`.
struct NormalSums {
    double jtj[3][3] = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
    double jte[3] = {0, 0, 0};

    // += wJ J^T and wJ e for one residual e with gradient J (wJ = w * J).
    void addOuter(const Eigen::Vector3d &wJ, const Eigen::Vector3d &J, double e) {
        for (int j = 0; j < 3; ++j)
            for (int i = 0; i < 3; ++i) jtj[i][j] += wJ(i) * J(j);
        for (int i = 0; i < 3; ++i) jte[i] += wJ(i) * e;
    }
    // += w J^T J and w J^T e for two residuals e with a 2x3 Jacobian J.
    void addNormal(double w, const Eigen::Matrix<double, 2, 3> &J, const Eigen::Vector2d &e) {
        double wJt[3][2];
        for (int i = 0; i < 3; ++i) wJt[i][0] = w * J(0, i), wJt[i][1] = w * J(1, i);
        for (int j = 0; j < 3; ++j)
            for (int i = 0; i < 3; ++i) jtj[i][j] += wJt[i][0] * J(0, j) + wJt[i][1] * J(1, j);
        for (int i = 0; i < 3; ++i) jte[i] += wJt[i][0] * e(0) + wJt[i][1] * e(1);
    }
    void store(Eigen::Matrix3d &JtJ, Eigen::Vector3d &Jte) const {
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) JtJ(i, j) = jtj[i][j];
            Jte(i) = jte[i];
        }
    }
};

// Weighted cost of (c, r) under the weights `w_old` (returned), and the linearization there.
double linearizeGeometric(const std::vector<Eigen::Vector2d> &pts, double tukey_c,
                          const Eigen::Vector2d &c, double r, const std::vector<double> *w_old,
                          GeoLinearization &lin) {
    // Sums in locals: stores through lin.w would otherwise alias them.
    NormalSums sums;
    double wsum = 0, cost = 0, old_cost = 0;
    double *w_new = lin.w.data();
    for (size_t k = 0; k < pts.size(); ++k) {
        const Eigen::Vector2d dvec = pts[k] - c;
        const double dist = dvec.norm();
        const double e = dist - r;
        if (w_old != nullptr) old_cost += (*w_old)[k] * e * e;
        const double w = w_new[k] = tukeyWeight(e, tukey_c);
        wsum += w;
        cost += w * e * e;
        if (w == 0.0 || dist == 0.0) continue;
        const Eigen::Vector3d J(-dvec.x() / dist, -dvec.y() / dist, -1.0);
        sums.addOuter(w * J, J, e);
    }
    sums.store(lin.JtJ, lin.Jte);
    lin.wsum = wsum;
    lin.cost = cost;
    return old_cost;
}

// Geometric LM on (cx, cy, r) minimising sum w_i (|p_i - c| - r)^2, Tukey weights with scale
// `tukey_c` re-evaluated every iteration (IRLS). A trial step's cost (under the current
// weights) and the linearization at it come from one pass: an accepted step is the next
// iteration's starting point.
void refineGeometric(const Eigen::Ref<const Points2> &xy, const std::vector<int> &rows,
                     double tukey_c, int iterations, Eigen::Vector2d &c, double &r) {
    double lambda = 1e-3;
    GeoLinearization cur{std::vector<double>(rows.size()), Eigen::Matrix3d::Zero(),
                         Eigen::Vector3d::Zero(), 0, 0};
    GeoLinearization trial = cur;
    std::vector<Eigen::Vector2d> pts(rows.size());  // the rows, contiguous
    for (size_t k = 0; k < rows.size(); ++k) pts[k] = xy.row(rows[k]).transpose();
    linearizeGeometric(pts, tukey_c, c, r, nullptr, cur);
    for (int it = 0; it < iterations; ++it) {
        if (cur.wsum < 3.0) return;
        const double before = cur.cost;
        bool improved = false;
        for (int attempt = 0; attempt < 8 && !improved; ++attempt) {
            Eigen::Matrix3d A = cur.JtJ;
            A.diagonal() *= (1.0 + lambda);
            const Eigen::Vector3d step = A.ldlt().solve(-cur.Jte);
            if (!step.allFinite()) return;
            const Eigen::Vector2d cn = c + step.head<2>();
            const double rn = r + step(2);
            if (rn > 0 && linearizeGeometric(pts, tukey_c, cn, rn, &cur.w, trial) <= before) {
                c = cn;
                r = rn;
                std::swap(cur, trial);
                lambda = std::max(lambda * 0.3, 1e-9);
                improved = true;
                if (step.norm() < 1e-9) return;
            } else {
                lambda *= 10.0;
            }
        }
        if (!improved) return;
    }
}

std::vector<int> inliersOf(const Eigen::Ref<const Points2> &xy, const std::vector<int> &rows,
                           const Eigen::Vector2d &c, double r, double threshold) {
    std::vector<int> in;
    for (int i : rows) {
        if (std::abs((xy.row(i).transpose() - c).norm() - r) <= threshold) in.push_back(i);
    }
    return in;
}

size_t inlierCount(const Eigen::Ref<const Points2> &xy, const std::vector<int> &rows,
                   const Eigen::Vector2d &c, double r, double threshold) {
    size_t count = 0;
    for (int i : rows) count += std::abs((xy.row(i).transpose() - c).norm() - r) <= threshold;
    return count;
}

void finish(const Eigen::Ref<const Points2> &xy, const CircleFitConfig &opt, CircleFit &fit) {
    double ss = 0;
    for (int i : fit.inlier_indices) {
        const double e = (xy.row(i).transpose() - fit.centre).norm() - fit.radius;
        ss += e * e;
    }
    fit.inliers = static_cast<int>(fit.inlier_indices.size());
    fit.rms_m = fit.inliers > 0 ? std::sqrt(ss / fit.inliers) : 0.0;
    fit.arc_coverage = arcCoverage(xy, fit.inlier_indices, fit.centre, opt.arc_sectors);
    fit.covariance = circleCovariance(xy, fit.inlier_indices, fit.centre, fit.radius);
}

}  // namespace

double arcCoverage(const Eigen::Ref<const Points2> &xy, const std::vector<int> &rows,
                   const Eigen::Vector2d &centre, int sectors) {
    if (sectors <= 0) throw std::invalid_argument("arcCoverage: sectors must be > 0");
    if (rows.empty()) return 0.0;
    std::vector<char> hit(static_cast<size_t>(sectors), 0);
    for (int i : rows) {
        if (i < 0 || i >= xy.rows())
            throw std::out_of_range("arcCoverage: row " + std::to_string(i) + " of " +
                                    std::to_string(xy.rows()));
        const double a = std::atan2(xy(i, 1) - centre.y(), xy(i, 0) - centre.x()) + kPi;
        int s = static_cast<int>(a / (2.0 * kPi) * sectors);
        hit[static_cast<size_t>(std::clamp(s, 0, sectors - 1))] = 1;
    }
    return static_cast<double>(std::count(hit.begin(), hit.end(), 1)) / sectors;
}

double CircleFit::radiusStd() const { return std::sqrt(std::max(covariance(2, 2), 0.0)); }

Eigen::Matrix3d circleCovariance(const Eigen::Ref<const Points2> &xy, const std::vector<int> &rows,
                                 const Eigen::Vector2d &centre, double radius,
                                 int fitted_parameters, double min_variance_m2) {
    const Eigen::Matrix3d unknown =
        Eigen::Matrix3d::Constant(std::numeric_limits<double>::infinity());
    const int n = static_cast<int>(rows.size());
    if (n < 3 || n <= fitted_parameters) return unknown;
    Eigen::Matrix3d JtJ = Eigen::Matrix3d::Zero();
    double ss = 0;
    for (int i : rows) {
        const Eigen::Vector2d v = xy.row(i).transpose() - centre;
        const double d = v.norm();
        ss += (d - radius) * (d - radius);
        if (!(d > 0)) continue;
        const Eigen::Vector3d J(-v.x() / d, -v.y() / d, -1.0);
        JtJ += J * J.transpose();
    }
    Eigen::Matrix3d inverse;
    double det = 0;
    bool invertible = false;
    JtJ.computeInverseAndDetWithCheck(inverse, det, invertible, 1e-12);
    if (!invertible) return unknown;
    return std::max(ss / (n - fitted_parameters), min_variance_m2) * inverse;
}

CircleFit fitCircleAlgebraic(const Eigen::Ref<const Points2> &xy) {
    CircleFit fit;
    std::vector<int> rows = finiteIndices(xy);
    Eigen::Vector2d c;
    double r;
    if (!taubin(xy, rows, c, r)) return fit;
    fit.valid = true;
    fit.centre = c;
    fit.radius = r;
    fit.inlier_indices = rows;
    CircleFitConfig opt;
    finish(xy, opt, fit);
    return fit;
}

namespace {

// fitCircle without its quality figures (finish): fitCircleRays replaces them when it refines.
CircleFit robustFit(const Eigen::Ref<const Points2> &xy, const CircleFitConfig &opt) {
    CircleFit fit;
    const std::vector<int> rows = finiteIndices(xy);
    const int n = static_cast<int>(rows.size());
    if (n < 3 || !(opt.inlier_threshold_m > 0)) return fit;
    const double thr = opt.inlier_threshold_m;
    auto inBounds = [&](double r) { return r >= opt.min_radius_m && r <= opt.max_radius_m; };

    // 1. Consensus: RANSAC over 3-point circles, adaptive number of trials.
    std::mt19937 rng(opt.seed);
    std::uniform_int_distribution<int> pick(0, n - 1);
    std::vector<int> best;
    int trials = opt.max_ransac_iterations;
    for (int it = 0; it < trials; ++it) {
        const int a = pick(rng), b = pick(rng), s = pick(rng);
        if (a == b || b == s || a == s) continue;
        Eigen::Vector2d c;
        double r;
        if (!circleFrom3(xy.row(rows[a]).transpose(), xy.row(rows[b]).transpose(),
                         xy.row(rows[s]).transpose(), c, r) ||
            !inBounds(r))
            continue;
        // Count first: most candidates lose, and only a winner's rows are kept.
        if (inlierCount(xy, rows, c, r, thr) <= best.size()) continue;
        {
            best = inliersOf(xy, rows, c, r, thr);
            const double w = static_cast<double>(best.size()) / n;
            const double p_fail = 1.0 - w * w * w;
            if (p_fail <= 1e-12) break;
            const int need = static_cast<int>(std::ceil(std::log(0.01) / std::log(p_fail)));
            trials = std::min(opt.max_ransac_iterations, std::max(need, 10));
        }
    }
    // No minimal sample in bounds (or all collinear): try the algebraic fit of everything.
    const std::vector<int> &seed_rows = best.size() >= 3 ? best : rows;

    // 2. Algebraic fit of the consensus set; 3. robust geometric refinement on all points.
    Eigen::Vector2d c;
    double r;
    if (!taubin(xy, seed_rows, c, r)) return fit;
    for (int round = 0; round < 3; ++round) {
        refineGeometric(xy, rows, 2.5 * thr, opt.refine_iterations, c, r);
    }
    fit.inlier_indices = inliersOf(xy, rows, c, r, thr);
    if (fit.inlier_indices.size() < 3 || !std::isfinite(r) || !inBounds(r)) {
        fit.inlier_indices.clear();
        return fit;
    }
    // Final least-squares polish on the inliers only (plain weights within the threshold).
    refineGeometric(xy, fit.inlier_indices, 1e6, opt.refine_iterations, c, r);
    if (!inBounds(r)) return CircleFit{};
    fit.valid = true;
    fit.centre = c;
    fit.radius = r;
    fit.inlier_indices = inliersOf(xy, rows, c, r, thr);
    return fit;
}

}  // namespace

CircleFit fitCircle(const Eigen::Ref<const Points2> &xy, const CircleFitConfig &opt) {
    CircleFit fit = robustFit(xy, opt);
    if (fit.valid) finish(xy, opt, fit);
    return fit;
}

namespace {

// Range-model residuals of one beam: (range residual / sigma_r, lateral miss / sigma_t).
struct RayPoint {
    Eigen::Vector2d origin, dir;  // beam origin and unit direction
    double range;                 // measured range (in the plane)
};

// Not inlined: GCC's inlined copy in the refinement loop ran 5 % slower (measured).
[[gnu::noinline]] Eigen::Vector2d rayResidual(const RayPoint &p, const Eigen::Vector3d &x,
                                              double sr, double st,
                                              Eigen::Matrix<double, 2, 3> *J = nullptr) {
    const Eigen::Vector2d w = x.head<2>() - p.origin;
    const double a = p.dir.dot(w);
    const double d2 = std::max(0.0, w.squaredNorm() - a * a);
    const double q = x(2) * x(2) - d2;
    const Eigen::Vector2d across = w - a * p.dir;  // half the gradient of d2 by the centre
    if (q > 0) {  // the beam meets the circle: residual along the beam to its near hit
        const double root = std::sqrt(q);
        if (J != nullptr) {
            J->setZero();
            J->block<1, 2>(0, 0) = (-p.dir - across / root).transpose() / sr;
            (*J)(0, 2) = x(2) / root / sr;
        }
        return Eigen::Vector2d((p.range - (a - root)) / sr, 0.0);
    }
    // the beam misses: along the beam to its closest approach, and the miss distance across
    const double d = std::sqrt(d2);
    if (J != nullptr) {
        J->setZero();
        J->block<1, 2>(0, 0) = -p.dir.transpose() / sr;
        if (d > 0) J->block<1, 2>(1, 0) = across.transpose() / (d * st);
        (*J)(1, 2) = -1.0 / st;
    }
    return Eigen::Vector2d((p.range - a) / sr, (d - x(2)) / st);
}

double cauchyWeight(double e2) { return 1.0 / (1.0 + e2 / (2.5 * 2.5)); }

// One pass of refineRays at x: Cauchy weights, normal equations and the weighted cost, as in
// linearizeGeometric (same expressions in the same order as the separate passes).
struct RayLinearization {
    std::vector<double> w;
    Eigen::Matrix3d JtJ;
    Eigen::Vector3d Jte;
    double cost;
};

double linearizeRays(const std::vector<RayPoint> &pts, double sr, double st,
                     const Eigen::Vector3d &x, const std::vector<double> *w_old,
                     RayLinearization &lin) {
    NormalSums sums;
    double cost = 0, old_cost = 0;
    double *w_new = lin.w.data();
    for (size_t k = 0; k < pts.size(); ++k) {
        Eigen::Matrix<double, 2, 3> J;
        const Eigen::Vector2d e = rayResidual(pts[k], x, sr, st, &J);
        const double e2 = e.squaredNorm();
        if (w_old != nullptr) old_cost += (*w_old)[k] * e2;
        const double w = w_new[k] = cauchyWeight(e2);
        cost += w * e2;
        sums.addNormal(w, J, e);
    }
    sums.store(lin.JtJ, lin.Jte);
    lin.cost = cost;
    return old_cost;
}

// IRLS Levenberg-Marquardt on (cx, cy, r) with analytic Jacobians (3 parameters); trial cost
// and next linearization in one pass, as in refineGeometric.
bool refineRays(const std::vector<RayPoint> &pts, double sr, double st, int iterations,
                Eigen::Vector3d &x) {
    double lambda = 1e-3;
    RayLinearization cur{std::vector<double>(pts.size()), Eigen::Matrix3d::Zero(),
                         Eigen::Vector3d::Zero(), 0};
    RayLinearization trial = cur;
    linearizeRays(pts, sr, st, x, nullptr, cur);
    for (int it = 0; it < iterations; ++it) {
        const double before = cur.cost;
        bool improved = false;
        for (int attempt = 0; attempt < 8 && !improved; ++attempt) {
            Eigen::Matrix3d A = cur.JtJ;
            A.diagonal() *= (1.0 + lambda);
            const Eigen::Vector3d step = A.ldlt().solve(-cur.Jte);
            if (!step.allFinite()) return false;
            const Eigen::Vector3d xn = x + step;
            const double after =
                xn(2) > 0 ? linearizeRays(pts, sr, st, xn, &cur.w, trial) : before + 1.0;
            if (after <= before) {
                x = xn;
                std::swap(cur, trial);
                lambda = std::max(lambda * 0.3, 1e-9);
                improved = true;
                // converged: a step under a micrometre, or no cost left to gain
                if (step.norm() < 1e-6 || before - after <= 1e-9 * before) return true;
            } else {
                lambda *= 10.0;
            }
        }
        if (!improved) return true;
    }
    return true;
}

}  // namespace

namespace {

// The range-model refinement of a valid orthogonal fit into `out` (its quality figures not yet
// computed); false when the orthogonal fit stands.
bool rayRefined(const Eigen::Ref<const Points2> &xy, const Eigen::Ref<const Points2> &origins,
                const CircleFitConfig &opt, const CircleFit &fit, CircleFit &out) {
    // Beams of the points near the orthogonal fit (clutter stays out), range spread first
    // from the orthogonal residuals.
    std::vector<RayPoint> pts;
    std::vector<double> ortho, facing, grazing;
    for (int i :
         inliersOf(xy, finiteIndices(xy), fit.centre, fit.radius, 2.0 * opt.inlier_threshold_m)) {
        const Eigen::Vector2d o = origins.row(i).transpose(), p = xy.row(i).transpose();
        const double range = (p - o).norm(), dist = (p - fit.centre).norm();
        if (!o.allFinite() || !(range > 1e-6) || !(dist > 0)) continue;
        pts.push_back({o, (p - o) / range, range});
        const double e = std::abs(dist - fit.radius);
        ortho.push_back(e);
        // Beam against the surface normal: residuals of beams facing the surface show the
        // range spread, of grazing beams the spread across the beam.
        const double c = std::abs(pts.back().dir.dot((p - fit.centre) / dist));
        if (c > 0.8) facing.push_back(e);
        if (c < 0.5) grazing.push_back(e);
    }
    if (pts.size() < 3) return false;
    // The range model holds when the spread lies along the beams. Where it is as wide across
    // them (bark roughness, registration jitter, dense scanners) the orthogonal fit is the
    // unbiased one, and the range model would run large (+1 cm on such arcs).
    auto median = [](std::vector<double> v) {
        std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
        return v[v.size() / 2];
    };
    if (facing.size() >= 5 && grazing.size() >= 5 &&
        median(facing) < opt.min_range_anisotropy * median(grazing))
        return false;
    const double st = std::max(opt.lateral_sigma_m, 1e-4);
    std::nth_element(ortho.begin(), ortho.begin() + static_cast<long>(ortho.size() / 2),
                     ortho.end());
    double sr = std::max(1.4826 * ortho[ortho.size() / 2], st);
    Eigen::Vector3d x(fit.centre.x(), fit.centre.y(), fit.radius);
    for (int round = 0; round < 3; ++round) {
        if (!refineRays(pts, sr, st, opt.refine_iterations, x)) return false;
        std::vector<double> res;
        for (const RayPoint &p : pts) res.push_back(std::abs(rayResidual(p, x, 1.0, 1.0).x()));
        std::nth_element(res.begin(), res.begin() + static_cast<long>(res.size() / 2), res.end());
        sr = std::max(1.4826 * res[res.size() / 2], st);
    }
    if (!x.allFinite() || x(2) < opt.min_radius_m || x(2) > opt.max_radius_m) return false;
    // A refinement that wandered off the points is not trusted: the range model moves a
    // sound circle by about the range noise, and keeps most of its inliers.
    const double moved = std::max(2.0 * opt.inlier_threshold_m, 0.25 * fit.radius);
    if ((x.head<2>() - fit.centre).norm() > moved || std::abs(x(2) - fit.radius) > moved)
        return false;
    out = fit;
    out.centre = x.head<2>();
    out.radius = x(2);
    out.inlier_indices =
        inliersOf(xy, finiteIndices(xy), out.centre, out.radius, opt.inlier_threshold_m);
    if (out.inlier_indices.size() < 0.8 * static_cast<double>(fit.inlier_indices.size()))
        return false;
    return true;
}

}  // namespace

CircleFit fitCircleRays(const Eigen::Ref<const Points2> &xy,
                        const Eigen::Ref<const Points2> &origins, const CircleFitConfig &opt) {
    if (origins.rows() != xy.rows())
        throw std::invalid_argument("fitCircleRays: " + std::to_string(origins.rows()) +
                                    " view origins for " + std::to_string(xy.rows()) + " points");
    CircleFit fit = robustFit(xy, opt);
    if (!fit.valid) return fit;
    // The orthogonal fit's quality figures only when it is the answer.
    CircleFit out;
    CircleFit &best = rayRefined(xy, origins, opt, fit, out) ? out : fit;
    finish(xy, opt, best);
    return best;
}

}  // namespace forestslam
