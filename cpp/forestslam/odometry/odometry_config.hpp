// Parameters of the tree odometry. Lengths in metres, angles in degrees where the name says so
// (radians elsewhere). The Python OdometryConfig mirrors these field by field (a parity test
// checks every default on both sides).
#pragma once

#include <string>

#include "forestslam/odometry/motion_model.hpp"
#include "forestslam/registration/fpfh_ransac.hpp"
#include "forestslam/registration/point_to_plane_icp.hpp"
#include "forestslam/registration/shape_registration.hpp"

namespace forestslam::odometry {

// Mutually exclusive nearest stems in XY after the constant-velocity prediction.
struct TreeMatchConfig {
    double gate_m = 1.0;
    double ratio = 1.0;  // < 1: drop pairs whose second-nearest target is within distance / ratio
};

struct RegistrationConfig {
    TreeMatchConfig trees;
    registration::ShapeRegistrationConfig shape;
    registration::IcpConfig icp;
    registration::FpfhConfig fpfh;  // its own `icp` is replaced by the one above
};

// method: "trees" (tree correspondences + shape-to-shape + point-to-plane ICP), "icp" (ICP from
// the constant-velocity prediction), "fpfh" (FPFH + RANSAC + ICP on the whole scan),
// "stem_centre_lm" (Shao et al.). mode: "local_map" registers each scan onto keyframes near it,
// "scan_to_scan" onto the previous scan.
struct OdometryConfig {
    std::string method = "trees";
    std::string mode = "local_map";
    bool deskew = true;  // spinning scans with per-point time, constant-velocity motion
    int min_stems = 2;   // fewer matched stems: ICP with the velocity prior, pose degraded
    // Source cloud for ICP: stem + ground points thinned to this voxel, at most this many.
    double source_voxel_m = 0.2;
    int max_source_points = 1200;
    // Local map: a keyframe every keyframe_distance_m / keyframe_yaw_deg, the last
    // local_map_keyframes kept, cropped to local_map_radius_m around the sensor.
    double keyframe_distance_m = 1.0;
    double keyframe_yaw_deg = 10.0;
    int local_map_keyframes = 10;
    double local_map_radius_m = 40.0;
    double map_voxel_m = 0.15;
    double stem_merge_m = 0.5;  // map stems closer than this in XY are one tree (newest kept)
    // Velocity prior of the fallback ICP (1 sigma per scan), and the largest correction from
    // the prediction accepted before the pose is declared degraded and the prediction kept.
    double prior_sigma_m = 0.1;
    double prior_sigma_deg = 1.0;
    double max_correction_m = 1.5;
    double max_correction_deg = 15.0;
    // Motion model (see MotionModelConfig): velocity clamps and the longest gap between scans.
    double max_speed_mps = MotionModelConfig{}.max_speed_mps;
    double max_turn_rate_dps = MotionModelConfig{}.max_turn_rate_dps;
    double max_stamp_gap_s = MotionModelConfig{}.max_gap_s;
    int fpfh_max_points = 6000;  // FPFH baseline: whole scan, voxelised, at most this many
    RegistrationConfig registration;
};

// Throws std::invalid_argument naming the field when a value is out of range or unknown.
void validate(const OdometryConfig &config);
MotionModelConfig motionModelConfig(const OdometryConfig &config);

}  // namespace forestslam::odometry
