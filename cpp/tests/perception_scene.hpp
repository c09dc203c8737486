// Test helper for the perception gtests: an exact ray-cast scan of vertical cylinders standing
// on a flat ground plane, with a VLP-16 beam pattern (16 beams, -15..15 deg, 1800 columns).
#pragma once

#include <cmath>
#include <random>
#include <vector>

#include "forestslam/common/types.hpp"
#include "forestslam/perception/config.hpp"

namespace forestslam::test {

struct Tree {
    double x, y, dbh;
};

struct SceneScan {
    Points3 points;
    Eigen::VectorXi ring;
};

inline perception::SensorGeometry vlp16Geometry() {
    perception::SensorGeometry g;
    g.image_rows = 16;
    g.image_cols = 1800;
    for (int k = 0; k < 16; ++k) g.vertical_angles_rad.push_back((-15.0 + 2.0 * k) * M_PI / 180);
    g.theta_v_rad = 2.0 * M_PI / 180;
    return g;
}

inline SceneScan castScan(const std::vector<Tree> &trees, double sensor_height, double noise,
                          unsigned seed) {
    const auto g = vlp16Geometry();
    std::mt19937 rng(seed);
    std::normal_distribution<double> n(0.0, noise);
    std::vector<Eigen::Vector3d> pts;
    std::vector<int> rings;
    for (int r = 0; r < g.image_rows; ++r) {
        const double e = g.vertical_angles_rad[static_cast<size_t>(r)];
        for (int c = 0; c < g.image_cols; ++c) {
            const double a = -M_PI + (c + 0.5) * 2 * M_PI / g.image_cols;
            const Eigen::Vector3d d(std::cos(e) * std::cos(a), std::cos(e) * std::sin(a),
                                    std::sin(e));
            double t = d.z() < -1e-6 ? -sensor_height / d.z() : INFINITY;
            for (const Tree &tr : trees) {
                const double dx = d.x(), dy = d.y(), rr = tr.dbh / 2;
                const double A = dx * dx + dy * dy, B = -2 * (dx * tr.x + dy * tr.y);
                const double C = tr.x * tr.x + tr.y * tr.y - rr * rr;
                const double disc = B * B - 4 * A * C;
                if (disc < 0) continue;
                const double th = (-B - std::sqrt(disc)) / (2 * A);
                const double z = th * d.z();
                if (th > 0 && th < t && z > -sensor_height && z < -sensor_height + 10) t = th;
            }
            if (!std::isfinite(t) || t > 60 || t < 0.5) continue;
            pts.push_back(d * (t + (noise > 0 ? n(rng) : 0.0)));
            rings.push_back(r);
        }
    }
    SceneScan s;
    s.points.resize(static_cast<Eigen::Index>(pts.size()), 3);
    s.ring.resize(static_cast<Eigen::Index>(pts.size()));
    for (size_t i = 0; i < pts.size(); ++i) {
        s.points.row(static_cast<Eigen::Index>(i)) = pts[i].transpose();
        s.ring(static_cast<Eigen::Index>(i)) = rings[i];
    }
    return s;
}

}  // namespace forestslam::test
