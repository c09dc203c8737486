#include "forestslam/sim/scan_synthesis.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace forestslam::sim {

namespace {

// Two independent standard normals from two hash uniforms (Box-Muller).
void hashNormalPair(uint64_t key, uint64_t salt, double &a, double &b) {
    const double u1 = hashUniform(key, salt), u2 = hashUniform(key, salt + 1);
    const double r = std::sqrt(-2.0 * std::log(u1)), phi = 2.0 * M_PI * u2;
    a = r * std::cos(phi);
    b = r * std::sin(phi);
}

constexpr uint64_t kDropoutSalt = 11, kNoiseSalt = 13;

}  // namespace

float returnIntensity(uint8_t surface, double cos_incidence, double noise, const ScanModel &model) {
    const bool leafy = surface == kFoliage || surface == kShrub;
    // Foliage returns above the threshold about 95 % of the time (1.55 +- 0.21 relative).
    const double base = leafy ? 1.55 : (surface == kGround ? 0.25 : 0.35);
    const double incidence = leafy ? 1.0 : 0.5 + 0.5 * cos_incidence;
    const double spread = leafy ? 0.21 : model.intensity_noise_rel;
    const double value = model.intensity_scale * base * incidence * (1.0 + spread * noise);
    return static_cast<float>(std::clamp(value, 0.0, 255.0));
}

SynthesizedScan synthesizeScan(const ForestScene &scene,
                               const Eigen::Ref<const Eigen::VectorXd> &knot_time,
                               const Eigen::Ref<const PoseRows> &knot_pose,
                               const Eigen::Ref<const Eigen::VectorXd> &group_time,
                               const Eigen::Ref<const IndexVector> &group,
                               const Eigen::Ref<const Points3> &local_dirs, const ScanModel &model,
                               uint64_t cast_seed, uint64_t noise_seed) {
    const Eigen::Index m = knot_time.size(), g_count = group_time.size(), n = local_dirs.rows();
    if (m == 0 || knot_pose.rows() != m)
        throw std::invalid_argument("need one pose (16 values) per knot time, at least one");
    if (group.size() != n) throw std::invalid_argument("need one group index per direction");
    for (Eigen::Index k = 1; k < m; ++k)
        if (!(knot_time[k] > knot_time[k - 1]))
            throw std::invalid_argument("knot times must increase");
    if (!knot_time.allFinite() || !knot_pose.allFinite() || !group_time.allFinite())
        throw std::invalid_argument("knot times, poses and group times must be finite");
    if (n > 0 && (group.minCoeff() < 0 || group.maxCoeff() >= g_count))
        throw std::invalid_argument("group index out of range");

    // Pose of every group.
    std::vector<Eigen::Matrix3d> rot(static_cast<size_t>(g_count));
    std::vector<Eigen::Vector3d> pos(static_cast<size_t>(g_count));
    auto knot = [&](Eigen::Index k, Eigen::Matrix3d &r, Eigen::Vector3d &p) {
        const auto row = knot_pose.row(k);
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) r(i, j) = row(4 * i + j);
            p[i] = row(4 * i + 3);
        }
    };
    Eigen::Index seg = 0;
    for (Eigen::Index g = 0; g < g_count; ++g) {
        const double t = group_time[g];
        Eigen::Matrix3d &r = rot[static_cast<size_t>(g)];
        Eigen::Vector3d &p = pos[static_cast<size_t>(g)];
        if (t <= knot_time[0]) {
            knot(0, r, p);
            continue;
        }
        if (t >= knot_time[m - 1]) {
            knot(m - 1, r, p);
            continue;
        }
        // Group times usually increase: continue the search from the last segment.
        if (t < knot_time[seg]) seg = 0;
        while (knot_time[seg + 1] < t) ++seg;
        if (t == knot_time[seg]) {
            knot(seg, r, p);
            continue;
        }
        if (t == knot_time[seg + 1]) {
            knot(seg + 1, r, p);
            continue;
        }
        const double a = (t - knot_time[seg]) / (knot_time[seg + 1] - knot_time[seg]);
        Eigen::Matrix3d r0, r1;
        Eigen::Vector3d p0, p1;
        knot(seg, r0, p0);
        knot(seg + 1, r1, p1);
        p = (1.0 - a) * p0 + a * p1;
        const Eigen::Quaterniond q0(r0), q1(r1);
        r = q0.slerp(a, q1).normalized().toRotationMatrix();
    }

    SynthesizedScan out;
    out.ray.resize(n);
    out.points.resize(n, 3);
    out.intensity.resize(n);
    out.surface.resize(n);
    out.object.resize(n);
    Eigen::Index kept = 0;
    for (Eigen::Index i = 0; i < n; ++i) {
        const Eigen::Vector3d local = local_dirs.row(i).transpose();
        const size_t g = static_cast<size_t>(group[i]);
        Ray ray;
        ray.origin = pos[g];
        ray.dir = rot[g] * local;
        const double norm = ray.dir.norm();
        if (!(norm > 0.0) || !std::isfinite(norm)) continue;
        ray.dir /= norm;
        ray.t_min = 0.0;  // anything closer than range_min still blocks the beam
        ray.t_max = model.range_max_m;
        ray.key = mixKey(cast_seed, static_cast<uint64_t>(i));
        const Hit hit = scene.cast(ray);
        if (!hit.valid() || hit.t < model.range_min_m) continue;
        const uint64_t key = mixKey(noise_seed, static_cast<uint64_t>(i));
        if (model.dropout_rate > 0.0 && hashUniform(key, kDropoutSalt) < model.dropout_rate)
            continue;
        double range_noise, intensity_noise;
        hashNormalPair(key, kNoiseSalt, range_noise, intensity_noise);
        const double range = hit.t + model.range_noise_m * range_noise;
        out.ray[kept] = i;
        out.points.row(kept) = (range / norm) * local.transpose();
        out.intensity[kept] =
            returnIntensity(hit.surface, hit.cos_incidence, intensity_noise, model);
        out.surface[kept] = hit.surface;
        out.object[kept] = hit.object;
        ++kept;
    }
    out.ray.conservativeResize(kept);
    out.points.conservativeResize(kept, 3);
    out.intensity.conservativeResize(kept);
    out.surface.conservativeResize(kept);
    out.object.conservativeResize(kept);
    return out;
}

}  // namespace forestslam::sim
