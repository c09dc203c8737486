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
    int32_t object = -1;         // row of the primitive in its own table
    double cos_incidence = 1.0;  // |cos| between the ray and the surface normal (1 in volumes)
    bool valid() const { return t < kInf; }
};

// A tree stem: a leaning (sheared: horizontal sections stay horizontal ellipses), tapered,
// elliptical cone with bark roughness. Height h is measured above `base` along z.
// Smooth section at h: ellipse with semi-axes semi_a * s(h), semi_b * s(h), s(h) = 1 - taper
// (h-1.3) centred at base.xy + shear * h; the a axis at azimuth `angle`. The bark adds bark_amp *
// n(azimuth, h), n a zero-mean (over azimuth) sum of sinusoids with |n| <= 1, so the mean diameter
// of the section at 1.3 m is exactly semi_a + semi_b (the truth DBH): n = sum_k w_k sin(L_k azimuth
// + m_k omega h + phase_k) / sum w, L = 4 9 17 31 lobes, m = 1 2 4 8, omega = 0.9 rad/m (integer
// lobes and octave-spaced vertical frequencies let the ray caster evaluate it with complex products
// instead of five transcendental calls).
struct Stem {
    Eigen::Vector3d base;   // axis point on the ground
    Eigen::Vector2d shear;  // horizontal axis offset per metre of height (tan of the lean)
    double semi_a = 0.1;    // semi-axes at breast height, m
    double semi_b = 0.1;
    double angle = 0.0;              // azimuth of the a axis, rad
    double taper = 0.0;              // relative radius loss per metre of height, 1/m
    double h_bottom = -0.3;          // stem starts this far below the base (buried), m
    double height = 10.0;            // top of the stem above the base, m
    double bark_amp = 0.0;           // bark roughness amplitude, m
    double phase[4] = {0, 0, 0, 0};  // bark noise phases (deterministic by seed)

    double barkNoise(double azimuth, double h) const;  // in [-1, 1]
    double radiusScale(double h) const { return 1.0 - taper * (h - kBreastHeight); }
};

// Per-primitive constants of the exact tests, computed once per scene (no divisions, square
// roots or trigonometry per ray for them). Stems: cos/sin of the section angle, inverse
// semi-axes, exp(i phase_k) of the bark terms.
struct StemCoeffs {
    double cos_angle = 1.0, sin_angle = 0.0;
    double inv_semi_a = 1.0, inv_semi_b = 1.0;
    double phase_re[4] = {1, 1, 1, 1}, phase_im[4] = {0, 0, 0, 0};
    explicit StemCoeffs(const Stem &stem);
};

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
