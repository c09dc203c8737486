// Synthetic forest scene for the TLS / feature unit tests: sloped ground, vertical stems and
// round boulders; ray-cast like a spinning LiDAR or sampled densely like a TLS map.
#pragma once

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam::test {

struct Stem {
    double x, y, radius;
};
struct Boulder {
    double x, y, z, radius;
};

struct Scene {
    std::vector<Stem> stems;
    std::vector<Boulder> boulders;
    double ground_z = -1.6;  // ground: z = ground_z + slope_x * x + slope_y * y
    double slope_x = 0.03, slope_y = -0.02;
    double stem_top_z = 8.0;

    double groundAt(double x, double y) const { return ground_z + slope_x * x + slope_y * y; }
};

inline Scene defaultScene(bool with_stems = true) {
    Scene s;
    if (with_stems) {
        s.stems = {{4.0, 1.0, 0.15}, {-3.0, 4.0, 0.22}, {-5.0, -4.0, 0.12}, {6.0, -5.0, 0.18},
                   {1.0, 7.0, 0.25}, {-8.0, 1.5, 0.2},  {9.0, 4.0, 0.16}};
    }
    s.boulders = {{2.5, -3.0, -1.4, 0.6},
                  {-6.0, -1.0, -1.3, 0.8},
                  {3.0, 5.0, -1.5, 0.5},
                  {-2.0, -7.0, -1.6, 0.9},
                  {7.0, 0.0, -1.5, 0.7}};
    return s;
}

// Ray-cast with `channels` beams between -15 and +15 deg, azimuth step az_step_deg, from the
// sensor pose T_world_sensor; points in the sensor frame, with ring numbers.
inline Points3 raycast(const Scene &scene, const Pose3 &T_world_sensor,
                       std::vector<std::uint16_t> &rings, int channels = 16,
                       double az_step_deg = 0.2, double max_range = 40.0, double noise_m = 0.0,
                       unsigned seed = 7) {
    std::mt19937 rng(seed);
    std::normal_distribution<double> noise(0.0, noise_m > 0 ? noise_m : 1.0);
    const Eigen::Vector3d o = T_world_sensor.translation();
    const Eigen::Matrix3d R = T_world_sensor.rotation();
    std::vector<Eigen::Vector3d> pts;
    rings.clear();
    const int n_az = static_cast<int>(std::round(360.0 / az_step_deg));
    for (int c = 0; c < channels; ++c) {
        const double el = (-15.0 + 30.0 * c / (channels - 1)) * M_PI / 180.0;
        for (int a = 0; a < n_az; ++a) {
            const double az = a * az_step_deg * M_PI / 180.0;
            const Eigen::Vector3d d_s(std::cos(el) * std::cos(az), std::cos(el) * std::sin(az),
                                      std::sin(el));
            const Eigen::Vector3d d = R * d_s;
            double best = max_range;
            // Ground plane: n.(o + t d) = ground_z with n = (-sx, -sy, 1).
            const Eigen::Vector3d n(-scene.slope_x, -scene.slope_y, 1.0);
            const double denom = n.dot(d);
            if (std::abs(denom) > 1e-9) {
                const double t = (scene.ground_z - n.dot(o)) / denom;
                if (t > 0.5 && t < best) best = t;
            }
            for (const auto &st : scene.stems) {
                const double ox = o.x() - st.x, oy = o.y() - st.y;
                const double A = d.x() * d.x() + d.y() * d.y();
                const double B = 2 * (ox * d.x() + oy * d.y());
                const double C = ox * ox + oy * oy - st.radius * st.radius;
                const double disc = B * B - 4 * A * C;
                if (A < 1e-12 || disc < 0) continue;
                const double t = (-B - std::sqrt(disc)) / (2 * A);
                const Eigen::Vector3d p = o + t * d;
                if (t > 0.5 && t < best && p.z() < scene.stem_top_z &&
                    p.z() > scene.groundAt(p.x(), p.y())) {
                    best = t;
                }
            }
            for (const auto &b : scene.boulders) {
                const Eigen::Vector3d oc = o - Eigen::Vector3d(b.x, b.y, b.z);
                const double B = 2 * oc.dot(d);
                const double C = oc.squaredNorm() - b.radius * b.radius;
                const double disc = B * B - 4 * C;
                if (disc < 0) continue;
                const double t = (-B - std::sqrt(disc)) / 2;
                if (t > 0.5 && t < best) best = t;
            }
            if (best >= max_range) continue;
            const double range = best + (noise_m > 0 ? noise(rng) : 0.0);
            pts.push_back(range * d_s);
            rings.push_back(static_cast<std::uint16_t>(c));
        }
    }
    Points3 out(static_cast<Eigen::Index>(pts.size()), 3);
    for (std::size_t i = 0; i < pts.size(); ++i) out.row(i) = pts[i].transpose();
    return out;
}

// Dense surface samples in the world frame (a "TLS map"): ground grid, full stem circles,
// boulder spheres, every spacing_m.
inline Points3 denseMap(const Scene &scene, double half_size = 14.0, double spacing_m = 0.05) {
    std::vector<Eigen::Vector3d> pts;
    for (double x = -half_size; x <= half_size; x += spacing_m) {
        for (double y = -half_size; y <= half_size; y += spacing_m) {
            pts.emplace_back(x, y, scene.groundAt(x, y));
        }
    }
    for (const auto &st : scene.stems) {
        const int n = static_cast<int>(2 * M_PI * st.radius / spacing_m) + 8;
        for (double z = scene.groundAt(st.x, st.y); z < scene.stem_top_z; z += spacing_m) {
            for (int k = 0; k < n; ++k) {
                const double a = 2 * M_PI * k / n;
                pts.emplace_back(st.x + st.radius * std::cos(a), st.y + st.radius * std::sin(a), z);
            }
        }
    }
    for (const auto &b : scene.boulders) {
        const int n = static_cast<int>(M_PI * b.radius / spacing_m) + 4;
        for (int i = 0; i <= n; ++i) {
            const double el = -M_PI / 2 + M_PI * i / n;
            const int m = static_cast<int>(2 * M_PI * b.radius * std::cos(el) / spacing_m) + 1;
            for (int k = 0; k < m; ++k) {
                const double az = 2 * M_PI * k / m;
                const Eigen::Vector3d p(b.x + b.radius * std::cos(el) * std::cos(az),
                                        b.y + b.radius * std::cos(el) * std::sin(az),
                                        b.z + b.radius * std::sin(el));
                if (p.z() >= scene.groundAt(p.x(), p.y())) pts.push_back(p);  // buried: unseen
            }
        }
    }
    Points3 out(static_cast<Eigen::Index>(pts.size()), 3);
    for (std::size_t i = 0; i < pts.size(); ++i) out.row(i) = pts[i].transpose();
    return out;
}

inline Pose3 makePose(double x, double y, double z, double roll, double pitch, double yaw) {
    Pose3 T = Pose3::Identity();
    T.linear() = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                  Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                  Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
                     .toRotationMatrix();
    T.translation() = Eigen::Vector3d(x, y, z);
    return T;
}

}  // namespace forestslam::test
