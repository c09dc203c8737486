// Virtual features of Shao et al. (2020, Sec. 3.3.1): stem centres with radius. Per laser ring
// (or per horizontal layer for TLS / map clouds without rings) connected runs of adjacent points
// are clustered, clusters as wide as a stem get a robust circle fit (common/circle_fit), and
// centres that continue vertically across rings / layers are kept as stem-centre features.
#pragma once

#include <cstdint>
#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam::features {

struct VirtualFeaturesConfig {
    double min_diameter_m = 0.06;  // expected stem diameters
    double max_diameter_m = 1.0;
    // Ring mode: adjacent points (in azimuth order) belong to one run while their distance is
    // below gap_m + gap_range_ratio * range.
    double gap_m = 0.05;
    double gap_range_ratio = 0.01;
    // Layer mode: horizontal slices of layer_thickness_m every layer_step_m, clustered by
    // connected occupied cells of cell_m in x-y.
    double layer_step_m = 0.25;
    double layer_thickness_m = 0.06;
    double cell_m = 0.04;
    double min_z_m = -1e9;  // layers only between these heights (frame z)
    double max_z_m = 1e9;
    int min_cluster_points = 5;
    double fit_inlier_m = 0.015;    // circle-fit inlier threshold
    double min_inlier_ratio = 0.7;  // share of cluster points that must be inliers
    double max_fit_rms_m = 0.015;
    // Vertical continuity: centres of different rings / layers link when horizontally closer
    // than max_centre_shift_m, vertically closer than max_vertical_gap_m and their radii differ
    // by at most radius_tolerance_m + max_taper * dz (stems taper slowly, round rocks and
    // bushes do not); a stem needs min_levels distinct rings / layers spanning
    // min_vertical_span_m.
    double max_centre_shift_m = 0.12;
    double max_vertical_gap_m = 1.5;
    double radius_tolerance_m = 0.04;
    double max_taper = 0.1;
    int min_levels = 2;
    double min_vertical_span_m = 0.5;
};

struct VirtualFeatures {
    Points3 centres;             // (V,3) circle centre (x, y) at the cluster's mean z
    Eigen::VectorXd radii;       // (V,)
    Eigen::VectorXi stem_ids;    // (V,) 0..S-1, centres of one stem share an id
    Eigen::VectorXi levels;      // (V,) ring number or layer index
    Eigen::VectorXd rms;         // (V,) circle-fit RMS residual (m)
    Points3 stems;               // (S,3) per stem: mean centre
    Eigen::VectorXd stem_radii;  // (S,) median radius
};

// Ring mode; rings (N,) must match points (std::invalid_argument otherwise); the sensor is at
// the frame origin.
VirtualFeatures extractVirtualFeaturesRings(const Eigen::Ref<const Points3> &points,
                                            const std::vector<std::uint16_t> &rings,
                                            const VirtualFeaturesConfig &config = {});

// Layer mode for clouds without rings (TLS, maps).
VirtualFeatures extractVirtualFeaturesLayers(const Eigen::Ref<const Points3> &points,
                                             const VirtualFeaturesConfig &config = {});

}  // namespace forestslam::features
