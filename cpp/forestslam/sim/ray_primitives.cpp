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
// Low lobes of the section's shape (Stem::irregularity), drifting slowly with height.
constexpr int kLowLobes[3] = {2, 3, 5};
constexpr double kLobeWeights[3] = {1.0, 0.7, 0.5};
constexpr double kLobeWeightSum = 2.2;
constexpr double kLobeDrift = kOmega / 4;  // rad/m; exp(i omega h) is then its 4th power

struct Complex {
    double re, im;
};
inline Complex mul(Complex a, Complex b) {
    return {a.re * b.re - a.im * b.im, a.re * b.im + a.im * b.re};
}

// Bark noise n at (azimuth, h) with z = exp(i azimuth), and its partial derivatives: the same
// sum as Stem::barkNoise, by products of unit complex numbers.
// w1 = exp(i omega h).
inline void barkNoiseAt(const StemCoeffs &c, Complex z, Complex w1, double &n, double &dn_daz,
                        double &dn_dh) {
    const Complex z2 = mul(z, z), z4 = mul(z2, z2), z8 = mul(z4, z4), z16 = mul(z8, z8);
    const Complex z9 = mul(z8, z), z17 = mul(z16, z), z31 = mul(mul(z17, z8), mul(z4, z2));
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

double Stem::flare(double h) const {
    if (flare_amp <= 0.0 || h >= flare_height) return 0.0;
    const double x = 1.0 - std::max(h, 0.0) / flare_height;
    return flare_amp * x * x * x;
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
    for (int k = 0; k < 3; ++k) {
        lobe_re[k] = std::cos(stem.lobe_phase[k]);
        lobe_im[k] = std::sin(stem.lobe_phase[k]);
    }
    double p_min = 1.0, p_max = 1.0;
    if (stem.sides >= 3) {
        // Circumradius c with perimeter 2 n c sin(pi / n) = 2 pi: the polygon's girth is the
        // unit circle's.
        const double half = M_PI / stem.sides;
        const double circum = M_PI / (stem.sides * std::sin(half));
        poly_apothem = circum * std::cos(half);
        poly_sector = 2.0 * half;
        p_min = poly_apothem;
        p_max = circum;
    }
    q_min = p_min * (1.0 - stem.irregularity);
    q_max = p_max * (1.0 + stem.irregularity);
}

SectionRadius sectionRadius(const Stem &stem, const StemCoeffs &c, double cos_phi, double sin_phi,
                            double h) {
    // Polygon factor p(phi) and its derivative.
    double p = 1.0, dp = 0.0;
    if (c.poly_sector > 0.0) {
        const double local = std::atan2(sin_phi, cos_phi) - stem.poly_angle;
        const double w = local - c.poly_sector * std::floor(local / c.poly_sector);
        const double off = w - 0.5 * c.poly_sector;
        const double co = std::cos(off);
        p = c.poly_apothem / co;
        dp = p * std::sin(off) / co;
    }
    // Low lobes 2, 3, 5 drifting by kLobeDrift rad/m.
    double m = 0.0, dm_dphi = 0.0, dm_dh = 0.0;
    // One cos/sin for the lobes' drift and the bark's vertical phase (its 4th power).
    Complex drift{1.0, 0.0};
    if (stem.irregularity > 0.0 || stem.bark_amp > 0.0)
        drift = {std::cos(kLobeDrift * h), std::sin(kLobeDrift * h)};
    if (stem.irregularity > 0.0) {
        const Complex z{cos_phi, sin_phi};
        const Complex z2 = mul(z, z), z3 = mul(z2, z), z5 = mul(z3, z2);
        const Complex zs[3] = {z2, z3, z5};
        for (int k = 0; k < 3; ++k) {
            const Complex e = mul(mul(zs[k], drift), Complex{c.lobe_re[k], c.lobe_im[k]});
            m += kLobeWeights[k] * e.im;
            dm_dphi += kLobeWeights[k] * kLowLobes[k] * e.re;
            dm_dh += kLobeWeights[k] * kLobeDrift * e.re;
        }
        m *= 1.0 / kLobeWeightSum;
        dm_dphi *= 1.0 / kLobeWeightSum;
        dm_dh *= 1.0 / kLobeWeightSum;
    }
    const double irr = stem.irregularity;
    const double q = p * (1.0 + irr * m);
    const double dq_dphi = dp * (1.0 + irr * m) + p * irr * dm_dphi;
    const double dq_dh = p * irr * dm_dh;
    // Taper and flare.
    const double scale = stem.radiusScale(h) + stem.flare(h);
    double dscale_dh = -stem.taper;
    if (stem.flare_amp > 0.0 && h > 0.0 && h < stem.flare_height) {
        const double x = 1.0 - h / stem.flare_height;
        dscale_dh -= 3.0 * stem.flare_amp * x * x / stem.flare_height;
    }
    SectionRadius out{scale * q, scale * dq_dphi, dscale_dh * q + scale * dq_dh};
    if (stem.bark_amp > 0.0) {
        const double eps = stem.bark_amp / (0.5 * (stem.semi_a + stem.semi_b));
        double n, dn_daz, dn_dh;
        const Complex d2 = mul(drift, drift);
        barkNoiseAt(c, Complex{cos_phi, sin_phi}, mul(d2, d2), n, dn_daz, dn_dh);
        out.r += eps * n;
        out.dr_dphi += eps * dn_daz;
        out.dr_dh += eps * dn_dh;
    }
    return out;
}

Eigen::MatrixX2d stemSection(const Stem &stem, double h, int n) {
    const StemCoeffs c(stem);
    Eigen::MatrixX2d xy(std::max(n, 0), 2);
    const double cx = stem.base.x() + stem.shear.x() * h, cy = stem.base.y() + stem.shear.y() * h;
    for (int k = 0; k < n; ++k) {
        const double phi = 2.0 * M_PI * k / n;
        const double cp = std::cos(phi), sp = std::sin(phi);
        const double r = sectionRadius(stem, c, cp, sp, h).r;
        const double u = r * cp * stem.semi_a, v = r * sp * stem.semi_b;
        xy(k, 0) = cx + c.cos_angle * u - c.sin_angle * v;
        xy(k, 1) = cy + c.sin_angle * u + c.cos_angle * v;
    }
    return xy;
}

bool intersectStem(const Stem &stem, const Ray &ray, double t_max, Hit &hit) {
    return intersectStem(stem, StemCoeffs(stem), ray, t_max, hit);
}

namespace {

// A ray in a stem's local coordinates, all linear in t: (u, v) the section coordinates normalised
// by the semi-axes and centred on the leaning axis, h the height above the base. The surface
// tests below are on this ray.
struct StemRay {
    const Stem &stem;
    const StemCoeffs &coeffs;
    double u0, du, v0, dv, h0, dh;
    double t_lo;               // the ray's t_min
    double duv, bq_uv, cq_uv;  // rho^2 = duv t^2 + bq_uv t + cq_uv
    // Where the ray enters the slab h_bottom <= h <= height (-inf: starts in it or runs along
    // it; +inf: never in it).
    double t_slab = -kInf;

    StemRay(const Stem &s, const StemCoeffs &c, const Ray &ray) : stem(s), coeffs(c) {
        const Eigen::Vector3d q = ray.origin - s.base;
        const Eigen::Vector3d &d = ray.dir;
        const double qx = q.x() - s.shear.x() * q.z(), qy = q.y() - s.shear.y() * q.z();
        const double dx = d.x() - s.shear.x() * d.z(), dy = d.y() - s.shear.y() * d.z();
        const double ca = c.cos_angle, sa = c.sin_angle;
        u0 = (ca * qx + sa * qy) * c.inv_semi_a;
        du = (ca * dx + sa * dy) * c.inv_semi_a;
        v0 = (-sa * qx + ca * qy) * c.inv_semi_b;
        dv = (-sa * dx + ca * dy) * c.inv_semi_b;
        h0 = q.z();
        dh = d.z();
        t_lo = ray.t_min;
        duv = du * du + dv * dv;
        bq_uv = 2.0 * (u0 * du + v0 * dv);
        cq_uv = u0 * u0 + v0 * v0;
        if (dh > 0.0)
            t_slab = (s.h_bottom - h0) / dh;
        else if (dh < 0.0)
            t_slab = (s.height - h0) / dh;
        else if (h0 < s.h_bottom || h0 > s.height)
            t_slab = kInf;
    }

    bool inSlab(double h) const { return h >= stem.h_bottom && h <= stem.height; }
    bool outsideSlab(double h) const { return h < stem.h_bottom || h > stem.height; }

    // First t in [t_lo, t_hi] where the ray is inside the cone rho <= c - kk (h - 1.3): through
    // its side, or (caps = true: the cone closed by the slab's planes, for brackets) where the
    // ray enters the slab already inside it. kInf if none.
    double coneEntry(double c, double kk, double t_hi, bool caps) const {
        const double C0 = c + kk * kBreastHeight - kk * h0, K = kk * dh;
        const double aq = duv - K * K, bq = bq_uv + 2.0 * C0 * K, cq = cq_uv - C0 * C0;
        auto ok = [&](double t) { return inSlab(h0 + t * dh) && C0 - K * t > 0.0; };
        const double t_side = enteringRoot(aq, bq, cq, t_lo, t_hi, ok);
        if (caps && t_slab > t_lo && t_slab < std::min(t_side, t_hi) &&
            (aq * t_slab + bq) * t_slab + cq <= 0.0 && C0 - K * t_slab > 0.0)
            return t_slab;
        return t_side;
    }

    // g(t) = rho - r(phi, h): > 0 outside the surface, < 0 inside; dg = dg/dt.
    double gap(double t, double &dg) const {
        const double u = u0 + t * du, v = v0 + t * dv, h = h0 + t * dh;
        const double rho = std::sqrt(u * u + v * v);
        if (!(rho > 0.0)) {
            dg = 0.0;
            return -1.0;
        }
        const double inv = 1.0 / rho;
        const SectionRadius s = sectionRadius(stem, coeffs, u * inv, v * inv, h);
        const double dphi_dt = (u * dv - v * du) * inv * inv;
        dg = (u * du + v * dv) * inv - s.dr_dphi * dphi_dt - s.dr_dh * dh;
        return rho - s.r;
    }
};

// The far end of the bracket of a shaped stem's surface: where the ray enters the inner
// envelope (cone parameters c_in, k_in), else for a grazing ray the first of kGrazingSamples
// points between the outer envelope's entry and its mirror image across the ray's closest
// approach to the axis that lies inside the surface. False when none does. Sampling the whole
// chord, not only the closest approach: a ray that clips a polygon corner or a bark ridge
// near the silhouette edge passes the axis closest where the section is narrower (a side's
// middle) and was lost (style b: 0.97 instead of 0.5 azimuth steps of the silhouette unsampled
// per side at 2 m, bench/dbh_edge_gap.py).
bool innerBracket(const StemRay &r, double c_in, double k_in, double t_out, double t_far,
                  double &t_in) {
    constexpr int kGrazingSamples = 48;
    t_in = c_in > 0.0 ? r.coneEntry(c_in, k_in, t_far, true) : kInf;
    if (t_in != kInf) return true;
    if (r.duv < 1e-18) return false;
    const double t_close = -(r.u0 * r.du + r.v0 * r.dv) / r.duv;
    const double t_end = std::min(std::max(2.0 * t_close - t_out, t_out), t_far);
    double dg;
    for (int k = 1; k <= kGrazingSamples; ++k) {
        t_in = t_out + (t_end - t_out) * k / kGrazingSamples;
        if (!r.outsideSlab(r.h0 + t_in * r.dh) && r.gap(t_in, dg) <= 0.0) return true;
    }
    return false;
}

// Newton on the bracket gap(lo) >= 0 >= gap(hi), bisecting when a step leaves it, from t.
double bracketedRoot(const StemRay &r, double lo, double hi, double t) {
    if (!(t > lo && t < hi)) t = 0.5 * (lo + hi);
    double t_hit = hi;
    for (int it = 0; it < 60; ++it) {
        double dg;
        const double gt = r.gap(t, dg);
        if (std::abs(gt) < 1e-9) return t;  // 1e-9 of the radius: sub-nanometre
        (gt > 0.0 ? lo : hi) = t;
        t_hit = hi;
        if (hi - lo < 1e-10) break;
        double next = dg != 0.0 ? t - gt / dg : lo;
        if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
        t = next;
    }
    return t_hit;
}

// The hit on a shaped stem (bark, flare, polygon, lobes): bracketed between the entries of an
// outer and an inner envelope cone, then solved. kInf if none within [t_lo, t_max].
double shapedStemHit(const StemRay &r, double ray_t_max, double t_max) {
    const Stem &stem = r.stem;
    // Envelopes of the surface over this stem (segment): the flare is largest at its bottom.
    const double eps = stem.bark_amp / (0.5 * (stem.semi_a + stem.semi_b));
    const double f_max = stem.flare(stem.h_bottom);
    const double c_out = r.coeffs.q_max * (1.0 + f_max) + eps, k_out = r.coeffs.q_max * stem.taper;
    const double c_in = r.coeffs.q_min - eps, k_in = r.coeffs.q_min * stem.taper;
    const double t_out = r.coneEntry(c_out, k_out, t_max, true);
    if (t_out == kInf) return kInf;
    // Past the outer envelope's entry the root is solved over the ray's whole range, not up to
    // t_max: the hit is then the same whatever the caller's current best (casts do not depend on
    // the order in which primitives are tested), and compared with t_max at the end.
    const double t_far = std::max(ray_t_max, t_max);
    double t_in;
    if (!innerBracket(r, c_in, k_in, t_out, t_far, t_in)) return kInf;
    // Newton starts at the entry of the middle envelope.
    const double t_mid = r.coneEntry(0.5 * (c_out + c_in), 0.5 * (k_out + k_in), t_far, true);
    const double t_hit = bracketedRoot(r, t_out, t_in, t_mid);
    if (r.outsideSlab(r.h0 + t_hit * r.dh) || t_hit > t_max || t_hit < r.t_lo) return kInf;
    return t_hit;
}

// |cos| of the incidence at the hit t on the stem: the section's normal is horizontal; in (u, v)
// it is e_rho - (dr/dphi / rho) e_phi, mapped to the world by the section's axes.
double stemCosIncidence(const StemRay &r, const Eigen::Vector3d &d, double t) {
    const StemCoeffs &c = r.coeffs;
    const double u = r.u0 + t * r.du, v = r.v0 + t * r.dv;
    const double rho = std::sqrt(u * u + v * v);
    double nu = u, nv = v;
    if (r.stem.shaped() && rho > 0.0) {
        const double cp = u / rho, sp = v / rho;
        const double slope = sectionRadius(r.stem, c, cp, sp, r.h0 + t * r.dh).dr_dphi / rho;
        nu = cp + slope * sp;
        nv = sp - slope * cp;
    }
    const double gx = nu * c.inv_semi_a, gy = nv * c.inv_semi_b;
    const double nx = c.cos_angle * gx - c.sin_angle * gy, ny = c.sin_angle * gx + c.cos_angle * gy;
    const double nn = std::sqrt(nx * nx + ny * ny);
    return nn > 0 ? std::abs(d.x() * nx + d.y() * ny) / nn : 1.0;
}

}  // namespace

bool intersectStem(const Stem &stem, const StemCoeffs &coeffs, const Ray &ray, double t_max,
                   Hit &hit) {
    if (ray.t_min > t_max) return false;
    const StemRay r(stem, coeffs, ray);
    // A smooth stem is its cone; a shaped one lies between two cones.
    const double t_hit = stem.shaped() ? shapedStemHit(r, ray.t_max, t_max)
                                       : r.coneEntry(1.0, stem.taper, t_max, false);
    if (t_hit == kInf) return false;
    hit.t = t_hit;
    hit.cos_incidence = stemCosIncidence(r, ray.dir, t_hit);
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
