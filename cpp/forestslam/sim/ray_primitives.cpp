#include "forestslam/sim/ray_primitives.hpp"

#include <algorithm>
#include <cmath>

namespace forestslam::sim {

namespace {

// Bark texture: integer lobe counts keep it periodic in azimuth (zero mean over a section);
// slow vertical phase drift makes furrows that wander along the stem.
constexpr int kLobes[4] = {4, 9, 17, 31};
constexpr double kVertical[4] = {0.8, 1.9, 3.7, 7.1};
constexpr double kWeights[4] = {1.0, 0.8, 0.6, 0.5};
constexpr double kWeightSum = 2.9;

uint64_t splitmix64(uint64_t x) {
    x += 0x9E3779B97F4A7C15ULL;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
    return x ^ (x >> 31);
}

// Smallest root t in [t_lo, t_hi] of a t^2 + b t + c = 0 at which f = a t^2 + b t + c goes from
// positive to negative (the ray enters) and `ok(t)` holds; kInf if none.
template <class Ok>
double enteringRoot(double a, double b, double c, double t_lo, double t_hi, Ok &&ok) {
    double roots[2];
    int n = 0;
    if (std::abs(a) < 1e-14) {
        if (std::abs(b) < 1e-14) return kInf;
        roots[n++] = -c / b;
    } else {
        const double disc = b * b - 4.0 * a * c;
        if (disc < 0.0) return kInf;
        const double sq = std::sqrt(disc);
        // Numerically stable pair.
        const double q = -0.5 * (b + (b >= 0 ? sq : -sq));
        double r0 = q / a;
        double r1 = q != 0.0 ? c / q : r0;
        if (r0 > r1) std::swap(r0, r1);
        roots[n++] = r0;
        roots[n++] = r1;
    }
    for (int i = 0; i < n; ++i) {
        const double t = roots[i];
        if (t < t_lo || t > t_hi) continue;
        if (2.0 * a * t + b > 0.0) continue;  // leaving, not entering
        if (ok(t)) return t;
    }
    return kInf;
}

}  // namespace

uint64_t mixKey(uint64_t a, uint64_t b) { return splitmix64(a ^ splitmix64(b + 0x632BE59BD9B4E019ULL)); }

double hashUniform(uint64_t key, uint64_t salt) {
    const uint64_t h = mixKey(key, salt);
    return (static_cast<double>(h >> 11) + 0.5) * (1.0 / 9007199254740992.0);
}

double Stem::barkNoise(double azimuth, double h) const {
    double s = 0.0;
    for (int k = 0; k < 4; ++k) s += kWeights[k] * std::sin(kLobes[k] * azimuth + kVertical[k] * h + phase[k]);
    return s / kWeightSum;
}

bool intersectStem(const Stem &stem, const Ray &ray, double t_max, Hit &hit) {
    return intersectStem(stem, std::cos(stem.angle), std::sin(stem.angle), ray, t_max, hit);
}

bool intersectStem(const Stem &stem, double cos_angle, double sin_angle, const Ray &ray,
                   double t_max, Hit &hit) {
    // Stem-local coordinates, linear in t: u, v normalised section coordinates, h height.
    const Eigen::Vector3d q = ray.origin - stem.base;
    const Eigen::Vector3d &d = ray.dir;
    const double qx = q.x() - stem.shear.x() * q.z(), qy = q.y() - stem.shear.y() * q.z();
    const double dx = d.x() - stem.shear.x() * d.z(), dy = d.y() - stem.shear.y() * d.z();
    const double ca = cos_angle, sa = sin_angle;
    const double u0 = (ca * qx + sa * qy) / stem.semi_a, du = (ca * dx + sa * dy) / stem.semi_a;
    const double v0 = (-sa * qx + ca * qy) / stem.semi_b, dv = (-sa * dx + ca * dy) / stem.semi_b;
    const double h0 = q.z(), dh = d.z();
    const double k = stem.taper;
    const double t_lo = ray.t_min;
    if (t_lo > t_max) return false;

    const double aq = du * du + dv * dv - k * k * dh * dh;
    const double bq_uv = 2.0 * (u0 * du + v0 * dv);
    const double cq_uv = u0 * u0 + v0 * v0;
    // Entry into the envelope whose section scale is c - k (h - 1.3).
    auto entry = [&](double c) {
        const double C0 = c + k * kBreastHeight - k * h0, K = k * dh;
        auto ok = [&](double t) {
            const double h = h0 + t * dh;
            return h >= stem.h_bottom && h <= stem.height && C0 - K * t > 0.0;
        };
        return enteringRoot(aq, bq_uv + 2.0 * C0 * K, cq_uv - C0 * C0, t_lo, t_max, ok);
    };
    const double r_mean = 0.5 * (stem.semi_a + stem.semi_b);
    const double eps = stem.bark_amp / r_mean;
    double t_hit;
    if (eps <= 0.0) {
        t_hit = entry(1.0);
        if (t_hit == kInf) return false;
    } else {
        const double t_out = entry(1.0 + eps);
        if (t_out == kInf) return false;
        auto g = [&](double t) {
            const double u = u0 + t * du, v = v0 + t * dv, h = h0 + t * dh;
            return std::sqrt(u * u + v * v) -
                   (stem.radiusScale(h) + eps * stem.barkNoise(std::atan2(v, u), h));
        };
        double t_in = entry(1.0 - eps);
        if (t_in == kInf) {
            // Grazing ray: bracket at its closest approach to the axis, if that is inside.
            const double duv = du * du + dv * dv;
            if (duv < 1e-18) return false;
            t_in = std::min(std::max(-(u0 * du + v0 * dv) / duv, t_out), t_max);
            const double h = h0 + t_in * dh;
            if (h < stem.h_bottom || h > stem.height || g(t_in) > 0.0) return false;
        }
        // Illinois regula falsi on the bracket g(lo) >= 0 >= g(hi): a few evaluations of the
        // bark function instead of a dozen bisections.
        double lo = t_out, hi = t_in, glo = g(lo), ghi = g(hi);
        t_hit = hi;
        int side = 0;
        for (int it = 0; it < 40 && hi - lo > 1e-9; ++it) {
            double m = glo != ghi ? hi - ghi * (hi - lo) / (ghi - glo) : 0.5 * (lo + hi);
            if (!(m > lo && m < hi)) m = 0.5 * (lo + hi);
            const double gm = g(m);
            t_hit = m;
            if (std::abs(gm) < 1e-7) break;  // 1e-7 of the radius: sub-micrometre
            if (gm > 0.0) {
                lo = m;
                glo = gm;
                if (side == 1) ghi *= 0.5;
                side = 1;
            } else {
                hi = m;
                ghi = gm;
                if (side == -1) glo *= 0.5;
                side = -1;
            }
            t_hit = hi;
        }
        const double h = h0 + t_hit * dh;
        if (h < stem.h_bottom || h > stem.height || t_hit > t_max || t_hit < t_lo) return false;
    }
    // Normal of the smooth section (horizontal), for the incidence angle.
    const double u = u0 + t_hit * du, v = v0 + t_hit * dv;
    const double gx = u / stem.semi_a, gy = v / stem.semi_b;
    const double nx = ca * gx - sa * gy, ny = sa * gx + ca * gy;
    const double nn = std::sqrt(nx * nx + ny * ny);
    hit.t = t_hit;
    hit.cos_incidence = nn > 0 ? std::abs(d.x() * nx + d.y() * ny) / nn : 1.0;
    return true;
}

bool intersectCylinder(const Cylinder &cyl, const Ray &ray, double t_max, Hit &hit) {
    const Eigen::Vector3d axis_full = cyl.p1 - cyl.p0;
    const double len = axis_full.norm();
    if (len <= 0.0) return false;
    const Eigen::Vector3d a = axis_full / len;
    const Eigen::Vector3d w = ray.origin - cyl.p0;
    const Eigen::Vector3d &d = ray.dir;
    const double da = d.dot(a), wa = w.dot(a);
    const Eigen::Vector3d dp = d - da * a, wp = w - wa * a;
    const double r2 = cyl.radius * cyl.radius;
    double best = kInf;
    Eigen::Vector3d normal = Eigen::Vector3d::Zero();
    auto ok_side = [&](double t) {
        const double s = wa + t * da;
        return s >= 0.0 && s <= len;
    };
    const double t_side =
        enteringRoot(dp.squaredNorm(), 2.0 * wp.dot(dp), wp.squaredNorm() - r2, ray.t_min, t_max, ok_side);
    if (t_side < best) {
        best = t_side;
        normal = wp + t_side * dp;
    }
    if (std::abs(da) > 1e-12) {
        for (const double s_cap : {0.0, len}) {
            const double t = (s_cap - wa) / da;
            if (t < ray.t_min || t > t_max || t >= best) continue;
            if ((wp + t * dp).squaredNorm() <= r2) {
                best = t;
                normal = a;
            }
        }
    }
    if (best == kInf) return false;
    const double nn = normal.norm();
    hit.t = best;
    hit.cos_incidence = nn > 0 ? std::abs(d.dot(normal)) / nn : 1.0;
    return true;
}

bool intersectFoliage(const FoliageEllipsoid &ell, int32_t index, const Ray &ray, double t_max,
                      Hit &hit) {
    const Eigen::Vector3d q = (ray.origin - ell.centre).cwiseQuotient(ell.radii);
    const Eigen::Vector3d e = ray.dir.cwiseQuotient(ell.radii);
    const double a = e.squaredNorm(), b = 2.0 * q.dot(e), c = q.squaredNorm() - 1.0;
    const double disc = b * b - 4.0 * a * c;
    if (disc <= 0.0 || a <= 0.0) return false;
    const double sq = std::sqrt(disc);
    const double t_enter = (-b - sq) / (2.0 * a), t_exit = (-b + sq) / (2.0 * a);
    // Free path from the geometric entry, so the outcome does not depend on clipping.
    const double free_path = -std::log(hashUniform(ray.key, static_cast<uint64_t>(index) * 7919ULL + ell.surface)) / ell.sigma;
    const double t = t_enter + free_path;
    if (t >= t_exit || t < ray.t_min || t > t_max) return false;
    hit.t = t;
    hit.cos_incidence = 1.0;
    return true;
}

}  // namespace forestslam::sim
