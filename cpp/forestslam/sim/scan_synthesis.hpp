// One simulated scan in a single pass: sensor poses along the sweep, ray directions in the world,
// first hits, then dropouts, range noise and intensity. Every random draw is a hash of
// (seed, ray row), so a scan depends only on its seeds, never on evaluation order.
#pragma once

#include <Eigen/Core>
#include <cstdint>

#include "forestslam/common/types.hpp"
#include "forestslam/sim/forest_scene.hpp"

namespace forestslam::sim {

// The sensor's measurement model (from its profile).
struct ScanModel {
    double range_min_m = 0.0;
    double range_max_m = 100.0;
    double range_noise_m = 0.0;         // standard deviation of the range, m
    double dropout_rate = 0.0;          // probability that a return is lost
    double intensity_scale = 100.0;     // the profile's intensity threshold (100 without one)
    double intensity_noise_rel = 0.12;  // relative noise of wood and ground intensity
};

// Intensity of a return (before noise): foliage and shrubs well above the threshold, bark, wood
// and ground well below it and brighter at normal incidence. noise: a standard normal draw.
float returnIntensity(uint8_t surface, double cos_incidence, double noise, const ScanModel &model);

struct SynthesizedScan {
    Eigen::Matrix<int64_t, Eigen::Dynamic, 1> ray;  // pattern row of each return, increasing
    Points3 points;                                 // sensor frame at the ray's own time
    Eigen::VectorXf intensity;
    Eigen::Matrix<uint8_t, Eigen::Dynamic, 1> surface;
    Eigen::Matrix<int32_t, Eigen::Dynamic, 1> object;
};

using PoseRows = Eigen::Matrix<double, Eigen::Dynamic, 16, Eigen::RowMajor>;
using IndexVector = Eigen::Matrix<int64_t, Eigen::Dynamic, 1>;

// knot_time (M,) increasing, knot_pose (M,16): row-major T_world_sensor at those times. Each group
// time gets the pose interpolated between its two knots (translation linearly, rotation by
// normalised quaternion interpolation, which equals slerp at the midpoint and for the small steps
// between knots; exactly the knot's pose at a knot time; clamped outside). Ray i (local_dirs
// row i, unit, sensor frame) is fired from the pose of group_time[group[i]]. The cast uses keys
// (cast_seed, i) as ForestScene::castRays does; dropouts and noise use noise_seed.
SynthesizedScan synthesizeScan(const ForestScene &scene,
                               const Eigen::Ref<const Eigen::VectorXd> &knot_time,
                               const Eigen::Ref<const PoseRows> &knot_pose,
                               const Eigen::Ref<const Eigen::VectorXd> &group_time,
                               const Eigen::Ref<const IndexVector> &group,
                               const Eigen::Ref<const Points3> &local_dirs, const ScanModel &model,
                               uint64_t cast_seed, uint64_t noise_seed);

}  // namespace forestslam::sim
