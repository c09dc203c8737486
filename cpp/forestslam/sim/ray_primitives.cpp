#include "forestslam/sim/ray_primitives.hpp"

#include <algorithm>
#include <cmath>

namespace forestslam::sim {

namespace {

// Bark texture: integer lobe counts keep it periodic in azimuth (zero mean over a section);
// slow vertical phase drift makes furrows that wander along the stem.
constexpr int kLobes[4] = {4, 9, 17, 31};
constexpr int kOctaves[4] = {1, 2, 4, 8};
constexpr double kOmega = 0.9;  // rad/m
constexpr double kWeights[4] = {1.0, 0.8, 0.6, 0.5};
constexpr double kWeightSum = 2.9;

struct Complex {
    double re, im;
};
inline Complex mul(Complex a, Complex b) {
    return {a.re * b.re - a.im * b.im, a.re * b.im + a.im * b.re};
}

// Bark noise n at (azimuth, h) with z = exp(i azimuth), and its partial derivatives: the same
// sum as Stem::barkNoise, by products of unit complex numbers.
inline void barkNoiseAt(const StemCoeffs &c, Complex z, double h, double &n, double &dn_daz,
                        double &dn_dh) {
    const Complex z2 = mul(z, z), z4 = mul(z2, z2), z8 = mul(z4, z4), z16 = mul(z8, z8);
    const Complex z9 = mul(z8, z), z17 = mul(z16, z), z31 = mul(mul(z17, z8), mul(z4, z2));
    const Complex w1{std::cos(kOmega * h), std::sin(kOmega * h)};
    const Complex w2 = mul(w1, w1), w4 = mul(w2, w2), w8 = mul(w4, w4);
    const Complex zs[4] = {z4, z9, z17, z31}, ws[4] = {w1, w2, w4, w8};
    n = dn_daz = dn_dh = 0.0;
    for (int k = 0; k < 4; ++k) {
        const Complex e = mul(mul(zs[k], ws[k]), Complex{c.phase_re[k], c.phase_im[k]});
        n += kWeights[k] * e.im;
        dn_daz += kWeights[k] * kLobes[k] * e.re;
        dn_dh += kWeights[k] * kOctaves[k] * kOmega * e.re;
    }
    n *= 1.0 / kWeightSum;
    dn_daz *= 1.0 / kWeightSum;
    dn_dh *= 1.0 / kWeightSum;
}

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

uint64_t mixKey(uint64_t a, uint64_t b) {
    return splitmix64(a ^ splitmix64(b + 0x632BE59BD9B4E019ULL));
}

double hashUniform(uint64_t key, uint64_t salt) {
    const uint64_t h = mixKey(key, salt);
    return (static_cast<double>(h >> 11) + 0.5) * (1.0 / 9007199254740992.0);
}

double Stem::barkNoise(double azimuth, double h) const {
    double s = 0.0;
    for (int k = 0; k < 4; ++k)
        s += kWeights[k] * std::sin(kLobes[k] * azimuth + kOctaves[k] * kOmega * h + phase[k]);
    return s / kWeightSum;
}

StemCoeffs::StemCoeffs(const Stem &stem)
    : cos_angle(std::cos(stem.angle)),
      sin_angle(std::sin(stem.angle)),
      inv_semi_a(1.0 / stem.semi_a),
      inv_semi_b(1.0 / stem.semi_b) {
    for (int k = 0; k < 4; ++k) {
        phase_re[k] = std::cos(stem.phase[k]);
        phase_im[k] = std::sin(stem.phase[k]);
    }
}

bool intersectStem(const Stem &stem, const Ray &ray, double t_max, Hit &hit) {
    return intersectStem(stem, StemCoeffs(stem), ray, t_max, hit);
}

bool intersectStem(const Stem &stem, const StemCoeffs &coeffs, const Ray &ray, double t_max,
                   Hit &hit) {
    // Stem-local coordinates, linear in t: u, v normalised section coordinates, h height.
    const Eigen::Vector3d q = ray.origin - stem.base;
    const Eigen::Vector3d &d = ray.dir;
    const double qx = q.x() - stem.shear.x() * q.z(), qy = q.y() - stem.shear.y() * q.z();
    const double dx = d.x() - stem.shear.x() * d.z(), dy = d.y() - stem.shear.y() * d.z();
    const double ca = coeffs.cos_angle, sa = coeffs.sin_angle;
    const double ia = coeffs.inv_semi_a, ib = coeffs.inv_semi_b;
    const double u0 = (ca * qx + sa * qy) * ia, du = (ca * dx + sa * dy) * ia;
    const double v0 = (-sa * qx + ca * qy) * ib, dv = (-sa * dx + ca * dy) * ib;
    const double h0 = q.z(), dh = d.z();
    const double k = stem.taper;
    const double t_lo = ray.t_min;
    if (t_lo > t_max) return false;

    const double aq = du * du + dv * dv - k * k * dh * dh;
    const double bq_uv = 2.0 * (u0 * du + v0 * dv);
    const double cq_uv = u0 * u0 + v0 * v0;
    // Entry into the envelope whose section scale is c - k (h - 1.3), up to t_hi.
    auto entry = [&](double c, double t_hi) {
        const double C0 = c + k * kBreastHeight - k * h0, K = k * dh;
        auto ok = [&](double t) {
            const double h = h0 + t * dh;
            return h >= stem.h_bottom && h <= stem.height && C0 - K * t > 0.0;
        };
        return enteringRoot(aq, bq_uv + 2.0 * C0 * K, cq_uv - C0 * C0, t_lo, t_hi, ok);
    };
    const double r_mean = 0.5 * (stem.semi_a + stem.semi_b);
    const double eps = stem.bark_amp / r_mean;
    double t_hit;
    if (eps <= 0.0) {
        t_hit = entry(1.0, t_max);
        if (t_hit == kInf) return false;
    } else {
        const double t_out = entry(1.0 + eps, t_max);
        if (t_out == kInf) return false;
        // Past the outer envelope's entry the root is solved over the ray's whole range, not up
        // to t_max: the hit is then the same whatever the caller's current best (casts do not
        // depend on the order in which primitives are tested), and compared with t_max at the
        // end.
        const double t_far = std::max(ray.t_max, t_max);
        // g(t) = rho - (s(h) + eps n): > 0 outside the bark surface, < 0 inside; dg = dg/dt.
        auto g = [&](double t, double &dg) {
            const double u = u0 + t * du, v = v0 + t * dv, h = h0 + t * dh;
            const double rho = std::sqrt(u * u + v * v);
            if (!(rho > 0.0)) {
                dg = 0.0;
                return -1.0;
            }
            double n, dn_daz, dn_dh;
            barkNoiseAt(coeffs, Complex{u / rho, v / rho}, h, n, dn_daz, dn_dh);
            const double daz_dt = (u * dv - v * du) / (rho * rho);
            dg = (u * du + v * dv) / rho + k * dh - eps * (dn_daz * daz_dt + dn_dh * dh);
            return rho - (stem.radiusScale(h) + eps * n);
        };
        double t_in = entry(1.0 - eps, t_far);
        if (t_in == kInf) {
            // Grazing ray: bracket at its closest approach to the axis, if that is inside.
            const double duv = du * du + dv * dv;
            if (duv < 1e-18) return false;
            t_in = std::min(std::max(-(u0 * du + v0 * dv) / duv, t_out), t_far);
            const double h = h0 + t_in * dh;
            double dg;
            if (h < stem.h_bottom || h > stem.height || g(t_in, dg) > 0.0) return false;
        }
        // Newton on the bracket g(lo) >= 0 >= g(hi) (the envelopes' entries), bisecting when a
        // step leaves it; starts at the smooth section's entry, a bark amplitude from the root.
        double lo = t_out, hi = t_in;
        double t = entry(1.0, t_far);
        if (!(t > lo && t < hi)) t = 0.5 * (lo + hi);
        t_hit = hi;
        for (int it = 0; it < 40; ++it) {
            double dg;
            const double gt = g(t, dg);
            if (std::abs(gt) < 1e-9) {  // 1e-9 of the radius: sub-nanometre
                t_hit = t;
                break;
            }
            (gt > 0.0 ? lo : hi) = t;
            t_hit = hi;
            if (hi - lo < 1e-10) break;
            double next = dg != 0.0 ? t - gt / dg : lo;
            if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
            t = next;
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

CylinderCoeffs::CylinderCoeffs(const Cylinder &cyl) {
    const Eigen::Vector3d axis_full = cyl.p1 - cyl.p0;
    length = axis_full.norm();
    axis = length > 0.0 ? Eigen::Vector3d(axis_full / length) : Eigen::Vector3d::Zero();
}

FoliageCoeffs::FoliageCoeffs(const FoliageEllipsoid &ell) : inv_radii(ell.radii.cwiseInverse()) {}

bool intersectCylinder(const Cylinder &cyl, const Ray &ray, double t_max, Hit &hit) {
    return intersectCylinder(cyl, CylinderCoeffs(cyl), ray, t_max, hit);
}

bool intersectCylinder(const Cylinder &cyl, const CylinderCoeffs &coeffs, const Ray &ray,
                       double t_max, Hit &hit) {
    const double len = coeffs.length;
    if (len <= 0.0) return false;
    const Eigen::Vector3d &a = coeffs.axis;
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
    const double t_side = enteringRoot(dp.squaredNorm(), 2.0 * wp.dot(dp), wp.squaredNorm() - r2,
                                       ray.t_min, t_max, ok_side);
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
    return intersectFoliage(ell, FoliageCoeffs(ell), index, ray, t_max, hit);
}

bool intersectFoliage(const FoliageEllipsoid &ell, const FoliageCoeffs &coeffs, int32_t index,
                      const Ray &ray, double t_max, Hit &hit) {
    const Eigen::Vector3d q = (ray.origin - ell.centre).cwiseProduct(coeffs.inv_radii);
    const Eigen::Vector3d e = ray.dir.cwiseProduct(coeffs.inv_radii);
    const double a = e.squaredNorm(), b = 2.0 * q.dot(e), c = q.squaredNorm() - 1.0;
    const double disc = b * b - 4.0 * a * c;
    if (disc <= 0.0 || a <= 0.0) return false;
    const double sq = std::sqrt(disc);
    const double inv_2a = 0.5 / a;
    const double t_enter = (-b - sq) * inv_2a, t_exit = (-b + sq) * inv_2a;
    if (t_enter > t_max || t_exit < ray.t_min) return false;  // before drawing the free path
    // Free path from the geometric entry, so the outcome does not depend on clipping.
    const double free_path =
        -std::log(hashUniform(ray.key, static_cast<uint64_t>(index) * 7919ULL + ell.surface)) /
        ell.sigma;
    const double t = t_enter + free_path;
    if (t >= t_exit || t < ray.t_min || t > t_max) return false;
    hit.t = t;
    hit.cos_incidence = 1.0;
    return true;
}

}  // namespace forestslam::sim
