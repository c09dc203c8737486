#include "forestslam/localization/acceptance.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace forestslam::localization {

namespace {
constexpr double kPi = 3.14159265358979323846;
constexpr double kLn10 = 2.302585092994046;
constexpr double kNegInf = -std::numeric_limits<double>::infinity();

Eigen::Vector2d rotate(double yaw, const Eigen::Vector2d &p) {
    const double c = std::cos(yaw), s = std::sin(yaw);
    return {c * p.x() - s * p.y(), s * p.x() + c * p.y()};
}
}  // namespace

DensityGrid::DensityGrid(const Eigen::Ref<const Points2> &xy, double cell_m, int half_window)
    : cell_(cell_m > 0 ? cell_m : 4.0) {
    const int w = std::max(0, half_window);
    window_area_ = std::pow((2 * w + 1) * cell_, 2);
    std::unordered_map<uint64_t, int> occupied;
    std::vector<std::pair<int64_t, int64_t>> cells;
    for (Eigen::Index i = 0; i < xy.rows(); ++i) {
        if (!std::isfinite(xy(i, 0)) || !std::isfinite(xy(i, 1))) continue;
        const auto ix = static_cast<int64_t>(std::floor(xy(i, 0) / cell_));
        const auto iy = static_cast<int64_t>(std::floor(xy(i, 1) / cell_));
        if (occupied[key(ix, iy)]++ == 0) cells.emplace_back(ix, iy);
    }
    for (const auto &[ix, iy] : cells) {
        const int n = occupied[key(ix, iy)];
        for (int64_t dx = -w; dx <= w; ++dx)
            for (int64_t dy = -w; dy <= w; ++dy) counts_[key(ix + dx, iy + dy)] += n;
    }
}

double DensityGrid::at(double x, double y) const {
    if (!std::isfinite(x) || !std::isfinite(y)) return 0.0;
    const auto it = counts_.find(key(static_cast<int64_t>(std::floor(x / cell_)),
                                     static_cast<int64_t>(std::floor(y / cell_))));
    return it == counts_.end() ? 0.0 : it->second / window_area_;
}

double chanceRate(double density, double gate_m) {
    return 1.0 - std::exp(-std::max(0.0, density) * kPi * gate_m * gate_m);
}

double gammaTailLn(int n, double x) {
    if (x <= 0 || n <= 0) return 0.0;
    // ln sum_{m < n} e^-x x^m / m!, terms built by recurrence, summed against the largest (at
    // m = min(n - 1, floor(x))).
    const double lx = std::log(x);
    const int mode = std::min(n - 1, static_cast<int>(x));
    const double log_mode = -x + mode * lx - std::lgamma(mode + 1.0);
    double sum = 1.0, t = 0.0;
    for (int m = mode - 1; m >= 0; --m) {  // t = log(term_m / term_mode)
        t += std::log(m + 1.0) - lx;
        if (t < -40) break;
        sum += std::exp(t);
    }
    t = 0.0;
    for (int m = mode + 1; m < n; ++m) {
        t += lx - std::log(double(m));
        if (t < -40) break;
        sum += std::exp(t);
    }
    return std::min(0.0, log_mode + std::log(sum));
}

double dbhLogRatio(double local_dbh, double map_dbh, const std::vector<float> &neighbourhood,
                   double sigma_m, double outlier_fraction) {
    if (neighbourhood.empty() || !(sigma_m > 0)) return 0.0;
    const double eps = std::clamp(outlier_fraction, 0.0, 1.0);
    // phi up to its constant factor, which cancels in the ratio.
    auto phi = [&](double diff) { return std::exp(-0.5 * std::pow(diff / sigma_m, 2)); };
    double f = 0.0;
    for (float d : neighbourhood) f += phi(local_dbh - d);
    f /= double(neighbourhood.size());
    const double own = phi(local_dbh - map_dbh);
    // f >= own / |N| > 0 when map_dbh is in the neighbourhood; far from every DBH both vanish.
    const double ratio = f > 1e-300 ? own / f : 1.0;
    return std::log((1 - eps) * ratio + eps);
}

double dbhEvidence(double sum_ln_ratio, double weight) {
    // ln(w e^s + 1 - w), stable for large s.
    const double s = sum_ln_ratio, w = std::clamp(weight, 1e-9, 1.0);
    if (w >= 1.0) return s;
    return s > 0 ? s + std::log(w + (1 - w) * std::exp(-s)) : std::log1p(w * std::expm1(s));
}

double poissonTailLog10(double mu, int k) {
    if (k <= 0) return 0.0;
    if (mu <= 0) return 300.0;  // no chance at all: as significant as representable
    // P(X >= k) = sum_{j>=k} e^-mu mu^j / j!, summed from the first term in log space.
    const double log_first = -mu + k * std::log(mu) - std::lgamma(k + 1.0);
    double sum = 0.0, term = 1.0;
    for (int j = k; j < k + 1000; ++j) {
        sum += term;
        term *= mu / (j + 1);
        if (term < 1e-16 * sum) break;
    }
    return std::max(0.0, -(log_first + std::log(sum)) / kLn10);
}

double truncatedProductTailLog10(double mu, double c, int k, double w, int extra_terms) {
    extra_terms = std::max(0, extra_terms);
    if (k + extra_terms <= 0) return 0.0;
    if (mu <= 0 && extra_terms == 0) return 300.0;
    c = std::max(0.0, c);
    const double s = std::max(0, k) * c + std::max(0.0, w);
    // P(S >= s) = sum_j Pois(j; mu) Q(j + e, s - j c), Q(n, x) = P(Gamma(n, 1) >= x)
    // = P(Poisson(x) <= n - 1) for integer n (e extra Exp(1) terms); summed in log space.
    auto logsumexp = [](double a, double b) {
        if (a == kNegInf) return b;
        if (b == kNegInf) return a;
        const double m = std::max(a, b);
        return m + std::log(std::exp(a - m) + std::exp(b - m));
    };
    const int jmax = static_cast<int>(std::max<double>(k, mu) + 10 * std::sqrt(mu + 1) + 60);
    double total = kNegInf;
    for (int j = extra_terms > 0 ? 0 : 1; j <= jmax; ++j) {
        const double log_pois =
            mu > 0 ? -mu + j * std::log(mu) - std::lgamma(j + 1.0) : (j == 0 ? 0.0 : kNegInf);
        if (log_pois == kNegInf) break;
        if (log_pois < total - 40) continue;             // Q <= 1: this term cannot matter
        const int n = j + extra_terms;                   // Exp(1) terms in the sum
        const double log_q = gammaTailLn(n, s - j * c);  // 0 when the j terms exceed s surely
        total = logsumexp(total, log_pois + log_q);
    }
    return std::max(0.0, -total / kLn10);
}

double seedEvidence(double deviation_m, double radius_m, int m, double floor_m) {
    if (m <= 0 || !(radius_m > 0) || !std::isfinite(deviation_m)) return 0.0;
    const double d = std::max(deviation_m, std::max(0.0, floor_m) * std::sqrt(double(m)));
    return d >= radius_m ? 0.0 : m * std::log(radius_m / d);
}

double seedEvidenceCube(double deviation_m, double half_width_m, int m, double floor_m) {
    if (m <= 0 || !(half_width_m > 0) || !std::isfinite(deviation_m)) return 0.0;
    const double d = std::max(deviation_m, std::max(0.0, floor_m) * std::sqrt(double(m)));
    // ln V_m(d) = (m / 2) ln pi - lgamma(m / 2 + 1) + m ln d.
    const double log_ball = 0.5 * m * std::log(kPi) - std::lgamma(0.5 * m + 1) + m * std::log(d);
    return std::max(0.0, m * std::log(2 * half_width_m) - log_ball);
}

double closeness(double density, double d_m, double gate_m, double floor_m) {
    const double p = chanceRate(density, gate_m);
    if (p <= 0) return 0.0;
    const double d = std::min(gate_m, std::max(d_m, floor_m));
    const double u = chanceRate(density, d);
    return u > 0 ? std::max(0.0, -std::log(u / p)) : 0.0;
}

ChanceEvidence chanceEvidence(int inliers, int trials, double expected, int seed_points,
                              int hypotheses, double closeness_sum, double seed, double dbh) {
    ChanceEvidence e;
    e.inliers = inliers;
    e.trials = trials;
    e.seed_points = std::min(seed_points, std::min(inliers, trials));
    // The seed trunks are inliers by construction: only the others are evidence.
    const double per_trunk = trials > 0 ? expected / trials : 0.0;
    e.expected = per_trunk * (trials - e.seed_points);
    const int k = inliers - e.seed_points;
    e.closeness = closeness_sum;
    const double c = per_trunk > 0 ? -std::log(std::min(1.0, per_trunk)) : 0.0;
    e.seed = std::max(0.0, seed);
    e.dbh = std::isfinite(dbh) ? dbh : 0.0;
    const int extra = e.seed > 0;  // Exp(1) terms beside the inliers'
    double tail = 0.0;
    if (closeness_sum < 0 || per_trunk <= 0) {
        tail = poissonTailLog10(e.expected, k);
        // Fisher: -ln of the product of 1 + extra independent p-values is Gamma(1 + extra).
        if (extra > 0) tail = -gammaTailLn(1 + extra, tail * kLn10 + e.seed) / kLn10;
    } else {
        tail = truncatedProductTailLog10(e.expected, c, k, closeness_sum + e.seed, extra);
    }
    // The DBH likelihood ratio (an e-value under a chance pose) divides the p-value.
    e.significance = tail + e.dbh / kLn10 - std::log10(std::max(1, hypotheses));
    return e;
}

std::vector<double> leaveOneOutRadii(const Points2 &local, const Points2 &map,
                                     const std::vector<std::pair<int, int>> &pairs) {
    const size_t n = pairs.size();
    if (n < 4) return {};
    Eigen::Vector2d sp = Eigen::Vector2d::Zero(), sq = Eigen::Vector2d::Zero();
    double sdot = 0, scross = 0, spp = 0;
    auto P = [&](size_t k) { return Eigen::Vector2d(local.row(pairs[k].first).transpose()); };
    auto Q = [&](size_t k) { return Eigen::Vector2d(map.row(pairs[k].second).transpose()); };
    for (size_t k = 0; k < n; ++k) {
        const Eigen::Vector2d p = P(k), q = Q(k);
        sp += p;
        sq += q;
        sdot += p.dot(q);
        scross += p.x() * q.y() - p.y() * q.x();
        spp += p.squaredNorm();
    }
    std::vector<double> out(n);
    const double m = double(n - 1);
    const double a = 1.0 + 1.0 / m;  // own noise + the fit's translation at the centroid
    for (size_t k = 0; k < n; ++k) {
        const Eigen::Vector2d p = P(k), q = Q(k);
        const Eigen::Vector2d lc = (sp - p) / m, mc = (sq - q) / m;
        const double sxx = (sdot - p.dot(q)) - m * lc.dot(mc);
        const double sxy =
            (scross - (p.x() * q.y() - p.y() * q.x())) - m * (lc.x() * mc.y() - lc.y() * mc.x());
        const double yaw = std::atan2(sxy, sxx);
        const Eigen::Vector2d t = mc - rotate(yaw, lc);
        const Eigen::Vector2d e = rotate(yaw, p) + t - q;
        const double spread = (spp - p.squaredNorm()) - m * lc.squaredNorm();
        if (!(spread > 0)) {
            out[k] = e.norm();
            continue;
        }
        // The lever arm's perpendicular in the map frame, scaled by 1 / sqrt(S).
        const Eigen::Vector2d r = p - lc;
        const Eigen::Vector2d v = rotate(yaw, Eigen::Vector2d(-r.y(), r.x())) / std::sqrt(spread);
        const double vv = v.squaredNorm(), ve = v.dot(e);
        const double mahalanobis2 = (e.squaredNorm() - ve * ve / (a + vv)) / a;
        out[k] = std::sqrt(std::max(0.0, mahalanobis2) * std::sqrt(a * (a + vv)));
    }
    return out;
}

AcceptanceVerdict judge(const ChanceEvidence &best, double runner_up_fraction,
                        const AcceptanceConfig &config) {
    AcceptanceVerdict v;
    if (best.inliers < config.min_inliers) {
        v.reason = "too few inliers";
    } else if (best.significance < config.min_significance) {
        v.reason = "not significant: inliers explained by chance at this map density";
    } else if (runner_up_fraction >= config.ambiguity_ratio) {
        v.reason = "ambiguous: second-best hypothesis nearly as good";
    } else {
        v.accepted = true;
    }
    return v;
}

}  // namespace forestslam::localization
