// Synthetic forest scenes for the registration tests: vertical stems as sampled cylinders on a
// gently sloped ground patch, seeded.
#pragma once

#include <random>
#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam::synth {

struct Stem {
    double x, y, radius;
};

inline std::vector<Stem> randomStems(int count, double half_extent, unsigned seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> pos(-half_extent, half_extent), rad(0.08, 0.25);
    std::vector<Stem> stems;
    while (static_cast<int>(stems.size()) < count) {
        Stem s{pos(rng), pos(rng), rad(rng)};
        bool ok = std::hypot(s.x, s.y) > 2.0;
        for (const auto &o : stems) ok = ok && std::hypot(s.x - o.x, s.y - o.y) > 2.0;
        if (ok) stems.push_back(s);
    }
    return stems;
}

inline double groundZ(double x, double y) {
    return -1.5 + 0.05 * x - 0.03 * y + 0.1 * std::sin(0.3 * x);
}

// Full-circumference stem points between ground+0.2 and ground+4 m, plus a ground grid.
inline Points3 sceneCloud(const std::vector<Stem> &stems, double half_extent, unsigned seed,
                          double noise_m = 0.0) {
    std::mt19937 rng(seed);
    std::normal_distribution<double> noise(0.0, noise_m > 0 ? noise_m : 1e-12);
    std::vector<Eigen::Vector3d> pts;
    for (const auto &s : stems) {
        const double z0 = groundZ(s.x, s.y);
        for (double z = 0.2; z < 4.0; z += 0.1)
            for (int a = 0; a < 24; ++a) {
                const double t = 2.0 * M_PI * a / 24.0;
                pts.emplace_back(s.x + s.radius * std::cos(t), s.y + s.radius * std::sin(t),
                                 z0 + z);
            }
    }
    for (double x = -half_extent; x <= half_extent; x += 0.5)
        for (double y = -half_extent; y <= half_extent; y += 0.5)
            pts.emplace_back(x, y, groundZ(x, y));
    Points3 out(pts.size(), 3);
    for (size_t i = 0; i < pts.size(); ++i)
        out.row(i) = (pts[i] + (noise_m > 0 ? Eigen::Vector3d(noise(rng), noise(rng), noise(rng))
                                            : Eigen::Vector3d::Zero()))
                         .transpose();
    return out;
}

}  // namespace forestslam::synth
