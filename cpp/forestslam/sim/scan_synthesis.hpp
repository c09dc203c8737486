// One simulated scan in a single pass: sensor poses along the sweep, ray directions in the world,
// first hits, then dropouts, range noise and intensity. Every random draw is a hash of
// (seed, ray row), so a scan depends only on its seeds, never on evaluation order.
#pragma once

#include <Eigen/Core>
#include <cstdint>

#include "forestslam/common/types.hpp"
#include "forestslam/sim/forest_scene.hpp"

namespace forestslam::sim {

// How one material returns the beam: its intensity at normal incidence and the reference range
// is log-normal around `median` (one draw per object with sigma_object, one per return with
// sigma_return), scaled by |cos incidence|^incidence_exponent.
struct Material {
    double median = 50.0;
    double sigma_return = 0.25;
    double sigma_object = 0.1;
    double incidence_exponent = 1.0;
};
constexpr int kSurfaceCount = 7;  // Surface values 0..6

// The sensor's measurement model. Intensity is in the sensor's own units (0..255) from the
// materials, the range and the incidence; it knows nothing of any downstream threshold.
struct ScanModel {
    double range_min_m = 0.0;
    double range_max_m = 100.0;
    // Range noise: standard deviation range_noise_m at normal incidence, plus (in quadrature)
    // the spread of the beam footprint over an inclined surface, 0.5 divergence range tan(inc)
    // (tan capped at 10).
    double range_noise_m = 0.0;
    double beam_divergence_rad = 0.0;
    // Dropouts: dropout_rate everywhere; below |cos incidence| = grazing_cos the loss grows
    // linearly to 1 at grazing; beyond far_fraction * range_max_m it grows linearly to 1 at
    // range_max_m.
    double dropout_rate = 0.0;
    double grazing_cos = 0.0;
    double far_fraction = 1.0;
    Material materials[kSurfaceCount];
    // Range fall-off: intensity times (reference_range_m / range)^range_exponent beyond the
    // reference, and falling linearly to half at 0 m below near_range_m (receiver optics).
    double reference_range_m = 5.0;
    double range_exponent = 0.0;
    double near_range_m = 0.0;
    uint64_t object_seed = 0;  // per-object reflectance draws (constant over a run)
};

// Intensity of a return: surface class, object row, range, |cos incidence|, and a standard
// normal draw for the per-return noise. Rounded to an integer in [0, 255] as drivers report it.
float returnIntensity(uint8_t surface, int32_t object, double range, double cos_incidence,
                      double noise, const ScanModel &model);

// Probability that a return is lost (range, |cos incidence|).
double dropoutProbability(double range, double cos_incidence, const ScanModel &model);

// Range noise standard deviation of a return.
double rangeSigma(double range, double cos_incidence, const ScanModel &model);

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
