#include "forestslam/common/circle_fit.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <stdexcept>
#include <string>

namespace forestslam {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Per-row weight: 1 without weights (the unweighted fit's expressions stay bit-identical, a
// product with 1.0 being exact).
inline double weightOf(const double *w, int row) { return w == nullptr ? 1.0 : w[row]; }

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
            double &r, const double *weights = nullptr) {
    const size_t n = rows.size();
    if (n < 3) return false;
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    double total = 0;
    for (int i : rows) {
        mean += weightOf(weights, i) * xy.row(i).transpose();
        total += weightOf(weights, i);
    }
    if (!(total > 0)) return false;
    mean /= weights == nullptr ? static_cast<double>(n) : total;
    double mxx = 0, myy = 0, mxy = 0, mxz = 0, myz = 0, mzz = 0;
    double extent = 0;
    for (int i : rows) {
        const double x = xy(i, 0) - mean.x(), y = xy(i, 1) - mean.y(), z = x * x + y * y;
        const double w = weightOf(weights, i);
        mxx += w * (x * x);
        myy += w * (y * y);
        mxy += w * (x * y);
        mxz += w * (x * z);
        myz += w * (y * z);
        mzz += w * (z * z);
        extent = std::max(extent, z);
    }
    const double inv = 1.0 / (weights == nullptr ? static_cast<double>(n) : total);
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
// Once that cost exceeds `reject_above` the pass stops (`lin` is then incomplete): its terms are
// non-negative and a rounded sum of non-negative terms never decreases, so the full cost would
// exceed it too, and the caller rejects such a step whatever the rest of the pass holds.
double linearizeGeometric(const std::vector<Eigen::Vector2d> &pts, const std::vector<double> &pt_w,
                          double tukey_c, const Eigen::Vector2d &c, double r,
                          const std::vector<double> *w_old, GeoLinearization &lin,
                          double reject_above = std::numeric_limits<double>::infinity()) {
    // Sums in locals: stores through lin.w would otherwise alias them.
    NormalSums sums;
    double wsum = 0, cost = 0, old_cost = 0;
    double *w_new = lin.w.data();
    for (size_t k = 0; k < pts.size(); ++k) {
        const Eigen::Vector2d dvec = pts[k] - c;
        const double dist = dvec.norm();
        const double e = dist - r;
        if (w_old != nullptr) old_cost += (*w_old)[k] * e * e;
        if (old_cost > reject_above) return old_cost;
        const double w = w_new[k] = pt_w[k] * tukeyWeight(e, tukey_c);
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
// iteration's starting point. `restarts` runs of up to `iterations` each, lambda reset.
void refineGeometric(const Eigen::Ref<const Points2> &xy, const std::vector<int> &rows,
                     double tukey_c, int iterations, Eigen::Vector2d &c, double &r,
                     const double *weights = nullptr, int restarts = 1) {
    GeoLinearization cur{std::vector<double>(rows.size()), Eigen::Matrix3d::Zero(),
                         Eigen::Vector3d::Zero(), 0, 0};
    GeoLinearization trial = cur;
    std::vector<Eigen::Vector2d> pts(rows.size());  // the rows, contiguous
    std::vector<double> pt_w(rows.size());          // their weights
    for (size_t k = 0; k < rows.size(); ++k) {
        pts[k] = xy.row(rows[k]).transpose();
        pt_w[k] = weightOf(weights, rows[k]);
    }
    linearizeGeometric(pts, pt_w, tukey_c, c, r, nullptr, cur);
    // Each restart (lambda afresh) begins where the last one ended, and `cur` is already the
    // linearization there: the same pass as a fresh one (the weights it was made under only
    // enter the cost it returned).
    for (int k = 0; k < restarts; ++k) {
        double lambda = 1e-3;
        for (int it = 0; it < iterations; ++it) {
            if (cur.wsum < 3.0) break;
            const double before = cur.cost;
            bool improved = false, converged = false;
            for (int attempt = 0; attempt < 8 && !improved; ++attempt) {
                Eigen::Matrix3d A = cur.JtJ;
                A.diagonal() *= (1.0 + lambda);
                const Eigen::Vector3d step = A.ldlt().solve(-cur.Jte);
                if (!step.allFinite()) break;
                const Eigen::Vector2d cn = c + step.head<2>();
                const double rn = r + step(2);
                if (rn > 0 && linearizeGeometric(pts, pt_w, tukey_c, cn, rn, &cur.w, trial,
                                                 before) <= before) {
                    c = cn;
                    r = rn;
                    std::swap(cur, trial);
                    lambda = std::max(lambda * 0.3, 1e-9);
                    improved = true;
                    converged = step.norm() < 1e-9;
                } else {
                    lambda *= 10.0;
                }
            }
            if (!improved || converged) break;
        }
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

// The summed weight of `rows` (their number without weights).
double weightSum(const std::vector<int> &rows, const double *weights) {
    if (weights == nullptr) return static_cast<double>(rows.size());
    double sum = 0;
    for (int i : rows) sum += weights[i];
    return sum;
}

double inlierWeight(const Eigen::Ref<const Points2> &xy, const std::vector<int> &rows,
                    const Eigen::Vector2d &c, double r, double threshold, const double *weights) {
    if (weights == nullptr) return static_cast<double>(inlierCount(xy, rows, c, r, threshold));
    double sum = 0;
    for (int i : rows)
        if (std::abs((xy.row(i).transpose() - c).norm() - r) <= threshold) sum += weights[i];
    return sum;
}

// circleCovariance with a weight per row (nullptr: 1 each, bit for bit the unweighted
// expressions): each row counts its weight times, sigma^2 from the weighted residuals over
// (summed weight - fitted_parameters), so integer weights give the covariance of the rows
// repeated that often.
Eigen::Matrix3d covarianceOfRows(const Eigen::Ref<const Points2> &xy, const std::vector<int> &rows,
                                 const double *weights, const Eigen::Vector2d &centre,
                                 double radius, int fitted_parameters, double min_variance_m2) {
    const Eigen::Matrix3d unknown =
        Eigen::Matrix3d::Constant(std::numeric_limits<double>::infinity());
    const double total = weightSum(rows, weights);
    if (rows.size() < 3 || total <= fitted_parameters) return unknown;
    Eigen::Matrix3d JtJ = Eigen::Matrix3d::Zero();
    double ss = 0;
    for (int i : rows) {
        const Eigen::Vector2d v = xy.row(i).transpose() - centre;
        const double d = v.norm(), w = weightOf(weights, i);
        ss += w * (d - radius) * (d - radius);
        if (!(d > 0)) continue;
        const Eigen::Vector3d J(-v.x() / d, -v.y() / d, -1.0);
        JtJ += w * J * J.transpose();
    }
    Eigen::Matrix3d inverse;
    double det = 0;
    bool invertible = false;
    JtJ.computeInverseAndDetWithCheck(inverse, det, invertible, 1e-12);
    if (!invertible) return unknown;
    return std::max(ss / (total - fitted_parameters), min_variance_m2) * inverse;
}

void finish(const Eigen::Ref<const Points2> &xy, const CircleFitConfig &opt, CircleFit &fit,
            const double *weights = nullptr) {
    double ss = 0;
    for (int i : fit.inlier_indices) {
        const double e = (xy.row(i).transpose() - fit.centre).norm() - fit.radius;
        ss += weightOf(weights, i) * (e * e);
    }
    fit.inliers = static_cast<int>(fit.inlier_indices.size());
    const double total = weightSum(fit.inlier_indices, weights);
    fit.rms_m = total > 0 ? std::sqrt(ss / total) : 0.0;
    fit.arc_coverage = arcCoverage(xy, fit.inlier_indices, fit.centre, opt.arc_sectors);
    fit.covariance =
        covarianceOfRows(xy, fit.inlier_indices, weights, fit.centre, fit.radius, 3, 1e-12);
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
    return covarianceOfRows(xy, rows, nullptr, centre, radius, fitted_parameters, min_variance_m2);
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
// Weighted RANSAC sampling: a draw j of [0, units) (units = the summed weight, rounded up)
// picks the finite row whose cumulative weight first exceeds j + 1/2 (scaled to the summed
// weight), so a row of integer weight w is drawn as often as w copies of it would be (the
// fit of the rows repeated by their weights, sample for sample); identity without weights.
struct Sampler {
    std::vector<double> cumulative;  // over the finite rows; empty without weights
    double total = 0;
    int units = 0;

    Sampler(const std::vector<int> &rows, const double *weights) {
        if (weights == nullptr) {
            units = static_cast<int>(rows.size());
            total = units;
            return;
        }
        for (int i : rows) cumulative.push_back(total += weights[i]);
        units = static_cast<int>(std::min(std::ceil(total), 2e9));
    }
    int row(int draw) const {  // index into the finite rows
        if (cumulative.empty()) return draw;
        const double at = (draw + 0.5) * total / units;
        const auto k = std::upper_bound(cumulative.begin(), cumulative.end(), at);
        return static_cast<int>(std::min<std::ptrdiff_t>(
            k - cumulative.begin(), static_cast<std::ptrdiff_t>(cumulative.size()) - 1));
    }
};

CircleFit robustFit(const Eigen::Ref<const Points2> &xy, const CircleFitConfig &opt,
                    const double *weights = nullptr) {
    CircleFit fit;
    const std::vector<int> rows = finiteIndices(xy);
    const int n = static_cast<int>(rows.size());
    if (n < 3 || !(opt.inlier_threshold_m > 0)) return fit;
    const double thr = opt.inlier_threshold_m;
    auto inBounds = [&](double r) { return r >= opt.min_radius_m && r <= opt.max_radius_m; };
    const Sampler sampler(rows, weights);
    if (!(sampler.total > 0) || sampler.units < 1) return fit;

    // 1. Consensus: RANSAC over 3-point circles, adaptive number of trials.
    std::mt19937 rng(opt.seed);
    std::uniform_int_distribution<int> pick(0, sampler.units - 1);
    std::vector<int> best;
    double best_weight = 0;
    int trials = opt.max_ransac_iterations;
    for (int it = 0; it < trials; ++it) {
        const int a = pick(rng), b = pick(rng), s = pick(rng);
        if (a == b || b == s || a == s) continue;
        Eigen::Vector2d c;
        double r;
        if (!circleFrom3(xy.row(rows[sampler.row(a)]).transpose(),
                         xy.row(rows[sampler.row(b)]).transpose(),
                         xy.row(rows[sampler.row(s)]).transpose(), c, r) ||
            !inBounds(r))
            continue;
        // Count first: most candidates lose, and only a winner's rows are kept.
        if (inlierWeight(xy, rows, c, r, thr, weights) <= best_weight) continue;
        {
            best = inliersOf(xy, rows, c, r, thr);
            best_weight = weightSum(best, weights);
            const double w = best_weight / sampler.total;
            const double p_fail = 1.0 - w * w * w;
            if (p_fail <= 1e-12) break;
            const int need = static_cast<int>(std::ceil(std::log(0.01) / std::log(p_fail)));
            trials = std::min(opt.max_ransac_iterations, std::max(need, 10));
        }
    }
    // No minimal sample in bounds (or all collinear): try the algebraic fit of everything.
    const std::vector<int> &seed_rows = best_weight >= 3 ? best : rows;

    // 2. Algebraic fit of the consensus set; 3. robust geometric refinement on all points.
    Eigen::Vector2d c;
    double r;
    if (!taubin(xy, seed_rows, c, r, weights)) return fit;
    refineGeometric(xy, rows, 2.5 * thr, opt.refine_iterations, c, r, weights, 3);
    fit.inlier_indices = inliersOf(xy, rows, c, r, thr);
    if (fit.inlier_indices.size() < 3 || !std::isfinite(r) || !inBounds(r)) {
        fit.inlier_indices.clear();
        return fit;
    }
    // Final least-squares polish on the inliers only (plain weights within the threshold).
    refineGeometric(xy, fit.inlier_indices, 1e6, opt.refine_iterations, c, r, weights);
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

// The weights of a weighted fit: one finite, non-negative value per row.
const double *checkedWeights(const Eigen::Ref<const Points2> &xy,
                             const Eigen::Ref<const Eigen::VectorXd> &weights, const char *who) {
    if (weights.size() != xy.rows())
        throw std::invalid_argument(std::string(who) + ": " + std::to_string(weights.size()) +
                                    " weights for " + std::to_string(xy.rows()) + " points");
    for (Eigen::Index i = 0; i < weights.size(); ++i) {
        if (!std::isfinite(weights(i)) || weights(i) < 0)
            throw std::invalid_argument(std::string(who) + ": weight " + std::to_string(i) +
                                        " is negative or not finite");
    }
    return weights.data();
}

}  // namespace

CircleFit fitCircleWeighted(const Eigen::Ref<const Points2> &xy,
                            const Eigen::Ref<const Eigen::VectorXd> &weights,
                            const CircleFitConfig &opt) {
    const double *w = checkedWeights(xy, weights, "fitCircleWeighted");
    CircleFit fit = robustFit(xy, opt, w);
    if (fit.valid) finish(xy, opt, fit, w);
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

// Stops once the cost under `w_old` exceeds `reject_above`, as linearizeGeometric.
double linearizeRays(const std::vector<RayPoint> &pts, const std::vector<double> &pt_w, double sr,
                     double st, const Eigen::Vector3d &x, const std::vector<double> *w_old,
                     RayLinearization &lin,
                     double reject_above = std::numeric_limits<double>::infinity()) {
    NormalSums sums;
    double cost = 0, old_cost = 0;
    double *w_new = lin.w.data();
    for (size_t k = 0; k < pts.size(); ++k) {
        Eigen::Matrix<double, 2, 3> J;
        const Eigen::Vector2d e = rayResidual(pts[k], x, sr, st, &J);
        const double e2 = e.squaredNorm();
        if (w_old != nullptr) old_cost += (*w_old)[k] * e2;
        if (old_cost > reject_above) return old_cost;
        const double w = w_new[k] = pt_w[k] * cauchyWeight(e2);
        cost += w * e2;
        sums.addNormal(w, J, e);
    }
    sums.store(lin.JtJ, lin.Jte);
    lin.cost = cost;
    return old_cost;
}

// IRLS Levenberg-Marquardt on (cx, cy, r) with analytic Jacobians (3 parameters); trial cost
// and next linearization in one pass, as in refineGeometric.
bool refineRays(const std::vector<RayPoint> &pts, const std::vector<double> &pt_w, double sr,
                double st, int iterations, Eigen::Vector3d &x) {
    double lambda = 1e-3;
    RayLinearization cur{std::vector<double>(pts.size()), Eigen::Matrix3d::Zero(),
                         Eigen::Vector3d::Zero(), 0};
    RayLinearization trial = cur;
    linearizeRays(pts, pt_w, sr, st, x, nullptr, cur);
    for (int it = 0; it < iterations; ++it) {
        const double before = cur.cost;
        bool improved = false;
        for (int attempt = 0; attempt < 8 && !improved; ++attempt) {
            Eigen::Matrix3d A = cur.JtJ;
            A.diagonal() *= (1.0 + lambda);
            const Eigen::Vector3d step = A.ldlt().solve(-cur.Jte);
            if (!step.allFinite()) return false;
            const Eigen::Vector3d xn = x + step;
            const double after = xn(2) > 0
                                     ? linearizeRays(pts, pt_w, sr, st, xn, &cur.w, trial, before)
                                     : before + 1.0;
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
// Median of values, each counted weights[k] times (the element at position floor(total / 2)
// of the values repeated by integer weights, sorted; that of nth_element without weights).
double weightedMedian(std::vector<double> v, const std::vector<double> &weights) {
    if (weights.empty()) {
        std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
        return v[v.size() / 2];
    }
    std::vector<size_t> order(v.size());
    for (size_t k = 0; k < order.size(); ++k) order[k] = k;
    std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return v[a] < v[b]; });
    double total = 0;
    for (double w : weights) total += w;
    const double half = std::floor(total / 2);
    double cumulative = 0;
    for (size_t k : order) {
        cumulative += weights[k];
        if (cumulative > half) return v[k];
    }
    return v[order.back()];
}

bool rayRefined(const Eigen::Ref<const Points2> &xy, const Eigen::Ref<const Points2> &origins,
                const CircleFitConfig &opt, const CircleFit &fit, CircleFit &out,
                const double *weights) {
    // Beams of the points near the orthogonal fit (clutter stays out), range spread first
    // from the orthogonal residuals.
    std::vector<RayPoint> pts;
    std::vector<double> ortho, facing, grazing, pt_w, facing_w, grazing_w;
    for (int i :
         inliersOf(xy, finiteIndices(xy), fit.centre, fit.radius, 2.0 * opt.inlier_threshold_m)) {
        const Eigen::Vector2d o = origins.row(i).transpose(), p = xy.row(i).transpose();
        const double range = (p - o).norm(), dist = (p - fit.centre).norm();
        if (!o.allFinite() || !(range > 1e-6) || !(dist > 0)) continue;
        pts.push_back({o, (p - o) / range, range});
        pt_w.push_back(weightOf(weights, i));
        const double e = std::abs(dist - fit.radius);
        ortho.push_back(e);
        // Beam against the surface normal: residuals of beams facing the surface show the
        // range spread, of grazing beams the spread across the beam.
        const double c = std::abs(pts.back().dir.dot((p - fit.centre) / dist));
        if (c > 0.8) facing.push_back(e), facing_w.push_back(pt_w.back());
        if (c < 0.5) grazing.push_back(e), grazing_w.push_back(pt_w.back());
    }
    if (pts.size() < 3) return false;
    // Medians over the weights (none without: the unweighted fit's nth_element).
    const std::vector<double> none;
    auto wts = [&](const std::vector<double> &w) -> const std::vector<double> & {
        return weights == nullptr ? none : w;
    };
    auto total = [&](const std::vector<double> &w, size_t count) {
        return weights == nullptr ? static_cast<double>(count)
                                  : std::accumulate(w.begin(), w.end(), 0.0);
    };
    // The range model holds when the spread lies along the beams. Where it is as wide across
    // them (bark roughness, registration jitter, dense scanners) the orthogonal fit is the
    // unbiased one, and the range model would run large (+1 cm on such arcs).
    if (total(facing_w, facing.size()) >= 5 && total(grazing_w, grazing.size()) >= 5 &&
        weightedMedian(facing, wts(facing_w)) <
            opt.min_range_anisotropy * weightedMedian(grazing, wts(grazing_w)))
        return false;
    const double st = std::max(opt.lateral_sigma_m, 1e-4);
    double sr = std::max(1.4826 * weightedMedian(ortho, wts(pt_w)), st);
    Eigen::Vector3d x(fit.centre.x(), fit.centre.y(), fit.radius);
    for (int round = 0; round < 3; ++round) {
        if (round > 0) {  // the range spread re-estimated from the last round's residuals
            std::vector<double> res;
            for (const RayPoint &p : pts) res.push_back(std::abs(rayResidual(p, x, 1.0, 1.0).x()));
            sr = std::max(1.4826 * weightedMedian(res, wts(pt_w)), st);
        }
        if (!refineRays(pts, pt_w, sr, st, opt.refine_iterations, x)) return false;
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
    if (weightSum(out.inlier_indices, weights) < 0.8 * weightSum(fit.inlier_indices, weights))
        return false;
    return true;
}

CircleFit raysFit(const Eigen::Ref<const Points2> &xy, const Eigen::Ref<const Points2> &origins,
                  const CircleFitConfig &opt, const double *weights, const char *who) {
    if (origins.rows() != xy.rows())
        throw std::invalid_argument(std::string(who) + ": " + std::to_string(origins.rows()) +
                                    " view origins for " + std::to_string(xy.rows()) + " points");
    CircleFit fit = robustFit(xy, opt, weights);
    if (!fit.valid) return fit;
    // The orthogonal fit's quality figures only when it is the answer.
    CircleFit out;
    CircleFit &best = rayRefined(xy, origins, opt, fit, out, weights) ? out : fit;
    finish(xy, opt, best, weights);
    return best;
}

}  // namespace

CircleFit fitCircleRays(const Eigen::Ref<const Points2> &xy,
                        const Eigen::Ref<const Points2> &origins, const CircleFitConfig &opt) {
    return raysFit(xy, origins, opt, nullptr, "fitCircleRays");
}

CircleFit fitCircleRaysWeighted(const Eigen::Ref<const Points2> &xy,
                                const Eigen::Ref<const Points2> &origins,
                                const Eigen::Ref<const Eigen::VectorXd> &weights,
                                const CircleFitConfig &opt) {
    return raysFit(xy, origins, opt, checkedWeights(xy, weights, "fitCircleRaysWeighted"),
                   "fitCircleRaysWeighted");
}

double circleArcJackknife(const Eigen::Ref<const Points2> &xy,
                          const Eigen::Ref<const Eigen::VectorXd> &weights,
                          const Eigen::Vector2d &centre, double radius, int blocks,
                          const CircleFitConfig &opt) {
    const double *w = checkedWeights(xy, weights, "circleArcJackknife");
    const double inf = std::numeric_limits<double>::infinity();
    if (blocks < 2 || !(radius > 0) || !centre.allFinite()) return inf;
    // The inliers in a canonical order (angle around the centre, then x, y, weight), so the
    // result does not depend on the rows' order; the angle runs from the widest gap.
    struct Row {
        double angle, x, y, w;
        int row;
    };
    std::vector<Row> in;
    for (int i : inliersOf(xy, finiteIndices(xy), centre, radius, opt.inlier_threshold_m)) {
        const Eigen::Vector2d v = xy.row(i).transpose() - centre;
        in.push_back({std::atan2(v.y(), v.x()), xy(i, 0), xy(i, 1), w[i], i});
    }
    const int n = static_cast<int>(in.size());
    if (n < 2 * blocks) return inf;
    std::sort(in.begin(), in.end(), [](const Row &a, const Row &b) {
        if (a.angle != b.angle) return a.angle < b.angle;
        if (a.x != b.x) return a.x < b.x;
        return a.y != b.y ? a.y < b.y : a.w < b.w;
    });
    int start = 0;
    double widest = -1;
    for (int k = 0; k < n; ++k) {
        const double next = k + 1 < n ? in[k + 1].angle : in[0].angle + 2 * kPi;
        if (next - in[k].angle > widest) widest = next - in[k].angle, start = (k + 1) % n;
    }
    std::rotate(in.begin(), in.begin() + start, in.end());
    std::vector<double> radii;
    for (int b = 0; b < blocks; ++b) {
        const int lo = b * n / blocks, hi = (b + 1) * n / blocks;
        std::vector<int> rows;
        for (int k = 0; k < n; ++k)
            if (k < lo || k >= hi) rows.push_back(in[k].row);
        Eigen::Vector2d c = centre;
        double r = radius;
        refineGeometric(xy, rows, 1e6, opt.refine_iterations, c, r, w);
        if (!std::isfinite(r) || !(r > 0)) return inf;
        radii.push_back(r);
    }
    const double mean = std::accumulate(radii.begin(), radii.end(), 0.0) / blocks;
    double ss = 0;
    for (double r : radii) ss += (r - mean) * (r - mean);
    return std::sqrt((blocks - 1.0) / blocks * ss);
}

}  // namespace forestslam
