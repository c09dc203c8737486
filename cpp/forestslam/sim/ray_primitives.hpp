// Analytic primitives of the simulated forest and their exact ray intersections.
// All lengths in metres, world frame, z up. A ray is origin + t * dir with |dir| = 1, so t is
// range.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <limits>

namespace forestslam::sim {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kBreastHeight = 1.3;

// Surface class of a return (drives intensity); values are part of the Python API.
enum Surface : uint8_t {
    kNone = 0,
    kGround = 1,
    kStem = 2,
    kBranch = 3,
    kFoliage = 4,
    kShrub = 5,
    kLog = 6,
};

struct Ray {
    Eigen::Vector3d origin;
    Eigen::Vector3d dir;  // unit length
    double t_min = 0.0;
    double t_max = kInf;
    uint64_t key = 0;  // per-ray random key: decides where it stops inside foliage
};

struct Hit {
    double t = kInf;
    uint8_t surface = kNone;
    int32_t object = -1;         // row of the primitive in its table (stems: Stem::tree if set)
    double cos_incidence = 1.0;  // |cos| between the ray and the surface normal (1 in volumes)
    bool valid() const { return t < kInf; }
};

// A tree stem, or one segment of it (a swept stem is a chain of segments whose axes meet at
// their shared heights; all share the tree's id, bark and lobes, so the surface is continuous).
// Height h is measured above `base` along z; horizontal sections stay horizontal (lean = shear).
// The section at h, in coordinates normalised by the semi-axes (u along the a axis at azimuth
// `angle`, v along b) and centred on the axis base.xy + shear * h, is the star-shaped curve
//   rho(phi) = (s(h) + f(h)) q(phi, h) + eps n(phi, h),   eps = bark_amp / ((semi_a + semi_b) / 2)
// with s(h) = 1 - taper (h - 1.3) the taper, f(h) = flare_amp (1 - h / flare_height)^3 for
// 0 <= h < flare_height (flare_amp below the ground, 0 above flare_height) the root flare,
// q = p(phi) (1 + irregularity m(phi, h)) the section's shape: p a regular polygon of `sides`
// sides (p = 1 when sides = 0) scaled to the perimeter of the unit circle, m a zero-mean sum of
// 2, 3 and 5 lobes drifting slowly with height (|m| <= 1), and n the bark: a zero-mean (over
// azimuth) sum of sinusoids with |n| <= 1: n = sum_k w_k sin(L_k phi + m_k omega h + phase_k) /
// sum w, L = 4 9 17 31 lobes, m = 1 2 4 8, omega = 0.9 rad/m (integer lobes and octave-spaced
// vertical frequencies let the ray caster evaluate it with complex products). The truth DBH is
// not a parameter: it is measured on this section (see stemSection).
struct Stem {
    Eigen::Vector3d base;   // axis point at h = 0 (the ground for an unswept stem)
    Eigen::Vector2d shear;  // horizontal axis offset per metre of height (tan of the lean)
    double semi_a = 0.1;    // semi-axes of the smooth section at breast height, m
    double semi_b = 0.1;
    double angle = 0.0;              // azimuth of the a axis, rad
    double taper = 0.0;              // relative radius loss per metre of height, 1/m
    double h_bottom = -0.3;          // this stem (segment) spans h_bottom..height above base, m
    double height = 10.0;            //
    double bark_amp = 0.0;           // bark roughness amplitude, m
    double phase[4] = {0, 0, 0, 0};  // bark noise phases (deterministic by seed)
    int32_t tree = -1;               // id reported as the hit's object (-1: the stem's row)
    double flare_amp = 0.0;          // relative radius added by the root flare at the ground
    double flare_height = 1.0;       // the flare is gone above this height, m
    int sides = 0;                   // polygonal section (0: smooth)
    double poly_angle = 0.0;         // azimuth of a polygon vertex in (u, v), rad
    double irregularity = 0.0;       // relative amplitude of the 2-3-5 lobes
    double lobe_phase[3] = {0, 0, 0};

    double barkNoise(double azimuth, double h) const;  // in [-1, 1]
    double radiusScale(double h) const { return 1.0 - taper * (h - kBreastHeight); }
    double flare(double h) const;
    bool shaped() const {
        return bark_amp > 0.0 || flare_amp > 0.0 || sides > 0 || irregularity > 0.0;
    }
};

// Per-primitive constants of the exact tests, computed once per scene (no divisions, square
// roots or trigonometry per ray for them). Stems: cos/sin of the section angle, inverse
// semi-axes, exp(i phase_k) of the bark and lobe terms, the polygon's constants and the bounds
// of the shape factor q.
struct StemCoeffs {
    double cos_angle = 1.0, sin_angle = 0.0;
    double inv_semi_a = 1.0, inv_semi_b = 1.0;
    double phase_re[4] = {1, 1, 1, 1}, phase_im[4] = {0, 0, 0, 0};
    double lobe_re[3] = {1, 1, 1}, lobe_im[3] = {0, 0, 0};
    double poly_apothem = 1.0, poly_sector = 0.0;  // p = apothem / cos(offset from mid-side)
    double q_min = 1.0, q_max = 1.0;
    explicit StemCoeffs(const Stem &stem);
};

// The normalised radial function rho(phi, h) of the stem's section (see Stem) and its partial
// derivatives; cos_phi, sin_phi the unit direction of phi.
struct SectionRadius {
    double r, dr_dphi, dr_dh;
};
SectionRadius sectionRadius(const Stem &stem, const StemCoeffs &coeffs, double cos_phi,
                            double sin_phi, double h);

// n points of the horizontal section h above the stem's base, world XY, at azimuths 2 pi k / n of
// the normalised section (rows of an (n, 2) matrix).
Eigen::MatrixX2d stemSection(const Stem &stem, double h, int n);

// Finite capped cylinder (dead branches, fallen logs).
struct Cylinder {
    Eigen::Vector3d p0, p1;
    double radius = 0.05;
    uint8_t surface = kBranch;
};

// Axis-aligned ellipsoid filled with foliage: a ray entering it stops after an exponentially
// distributed free path (extinction coefficient sigma, 1/m; Beer-Lambert), drawn from the ray key
// and the object index so the same ray always stops at the same place.
struct FoliageEllipsoid {
    Eigen::Vector3d centre;
    Eigen::Vector3d radii;
    double sigma = 1.0;
    uint8_t surface = kFoliage;
};

struct CylinderCoeffs {
    Eigen::Vector3d axis = Eigen::Vector3d::Zero();  // unit, p0 -> p1
    double length = 0.0;
    explicit CylinderCoeffs(const Cylinder &cyl);
};

struct FoliageCoeffs {
    Eigen::Vector3d inv_radii;
    explicit FoliageCoeffs(const FoliageEllipsoid &ell);
};

// Uniform (0,1) from a 64-bit key and a salt (splitmix64).
double hashUniform(uint64_t key, uint64_t salt);
uint64_t mixKey(uint64_t a, uint64_t b);

// Each returns true and fills `hit` (t, cos_incidence) when the ray hits within (ray.t_min, t_max].
bool intersectStem(const Stem &stem, const Ray &ray, double t_max, Hit &hit);
// Same, with the stem's constants precomputed by the caller (same result).
bool intersectStem(const Stem &stem, const StemCoeffs &coeffs, const Ray &ray, double t_max,
                   Hit &hit);
bool intersectCylinder(const Cylinder &cyl, const Ray &ray, double t_max, Hit &hit);
bool intersectCylinder(const Cylinder &cyl, const CylinderCoeffs &coeffs, const Ray &ray,
                       double t_max, Hit &hit);
bool intersectFoliage(const FoliageEllipsoid &ell, int32_t index, const Ray &ray, double t_max,
                      Hit &hit);
bool intersectFoliage(const FoliageEllipsoid &ell, const FoliageCoeffs &coeffs, int32_t index,
                      const Ray &ray, double t_max, Hit &hit);

}  // namespace forestslam::sim
