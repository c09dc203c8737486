// Parameters of the per-scan perception chain (Gupta et al. 2023, Sections 3.1-3.2) and the
// sensor geometry it needs. Lengths in metres, angles in radians. Python mirrors these in
// forestslam.perception.config (same names).
#pragma once

#include <limits>
#include <vector>

namespace forestslam::perception {

// What perception needs to know about the sensor (from forestslam.sensors.SensorProfile).
struct SensorGeometry {
    bool has_range_image = true;  // spinning / solid-state: one scan, projectable
    int image_rows = 16;          // range image size
    int image_cols = 1800;
    double horizontal_fov_rad = 6.283185307179586;  // 2 pi: columns wrap around
    std::vector<double> vertical_angles_rad;        // ascending beam elevations (rows)
    double theta_v_rad = 0.0349;                    // vertical angular resolution
    double azimuth_step_rad = 0.0;  // horizontal resolution (0: horizontal_fov / image_cols)
};

// Approximate progressive morphological filter (PCL). It runs on the lowest point of every
// `cell_size_m` grid cell (what the filter's min-grid sees anyway); every point is then ground
// when its cell's lowest point is ground and it lies within `cell_height_m` above it.
struct GroundConfig {
    double cell_size_m = 0.5;
    int max_window_cells = 5;  // windows 3, 5 cells (2.5 m: wider than any stem)
    double slope = 0.5;        // terrain slope tolerance (rise / run)
    double initial_distance_m = 0.2;
    double max_distance_m = 1.0;
    double base = 2.0;
    bool exponential = true;
    double cell_height_m = 0.2;   // points this close above their cell's ground point
    int min_component_cells = 6;  // ground islands smaller than this (stems in the blind
                                  // circle around the sensor) are not ground
    double max_range_m = 30.0;    // ground searched within this XY range (0 = everywhere)
};

// Adaptive ring-based normals and outlier filter (paper Algorithm 1).
struct NormalFilterConfig {
    bool adaptive = true;     // false: one fixed radius (the paper's ablation)
    double ring_min_m = 1.0;  // rings: geomspace(ring_min_m, ring_max_m, rings)
    double ring_max_m = 40.0;
    int rings = 12;
    double radius_scale = 1.5;             // delta_r = radius_scale * theta_V * (r_in + r_out) / 2
    double min_radius_m = 0.1;             // floor on delta_r (near rings)
    double max_radius_m = 1.0;             // cap on delta_r (far rings)
    double fixed_radius_m = 0.3;           // radius in fixed mode
    double max_normal_angle_rad = 0.5236;  // theta_th: normal within 30 deg of horizontal
    int min_neighbours = 5;                // N_min points in the radius neighbourhood
    int max_neighbours = 32;               // nearest neighbours used for the normal (speed cap)
    double min_height_m = 0.3;             // height band above the local ground grid kept for stems
    double max_height_m = 8.0;
    double voxel_m = 0.05;     // thinning before normals (0 = none)
    double map_voxel_m = 0.1;  // coarser thinning for map / tls clouds (dense, large)
};

struct SegmentationConfig {
    // Range-image divide-and-merge (Zhao et al. 2022).
    int block_cols = 32;               // local sub-images are column blocks of this width
    double beta_min_rad = 0.1745;      // Bogoslavskyi angle criterion between neighbours (10 deg)
    double max_neighbour_gap_m = 0.5;  // and an absolute distance cap
    int max_pixel_gap = 2;             // empty pixels bridged between neighbours
    double max_gap_m = 0.1;            // near the sensor: empty columns bridged up to this arc
                                       // (the normal filter's voxel thinning leaves such gaps)
    int min_votes = 2;                 // edge votes to merge two local clusters
    // 3D coarse clustering for map / tls clouds.
    double euclidean_tolerance_m = 0.2;
    // DBSCAN refinement: eps = k * theta_V * |mean_xy|, clamped.
    double dbscan_k = 1.25;
    int dbscan_min_neighbours = 2;
    double dbscan_min_eps_m = 0.08;
    double dbscan_max_eps_m = 1.0;
    double map_dbscan_eps_m = 0.25;  // eps for map / tls clouds (no theta_V)
    // SVD classification.
    int min_points = 8;
    double min_length_m = 0.4;           // extent along the principal axis
    double max_axis_angle_rad = 0.5236;  // principal axis within 30 deg of the ground normal
    double min_sv_ratio = 1.5;           // s0 / s1 (elongation)
    double max_width_m = 1.5;            // extent across the principal axis
    double merge_xy_m = 0.4;             // stems closer than this in XY are one tree
    double max_range_m = 30.0;           // stems farther from the sensor are ignored (0 = no limit)
    double ground_search_m = 2.0;        // ground points within this XY radius give the base height
};

struct DiameterConfig {
    double band_low_m = 1.15;  // breast-height band above local ground
    double band_high_m = 1.45;
    double band_max_half_m = 1.0;  // widened around 1.3 m up to this half-height if too few points
    int min_band_points = 20;
    double min_radius_m = 0.025;  // fits outside [min, max] radius are rejected
    double max_radius_m = 0.75;
    double inlier_threshold_m = 0.03;
    double min_arc_coverage = 0.1;
    double map_min_arc_coverage = 0.25;  // accumulated maps see stems from many sides
    int cylinder_iterations = 50;
    int cylinder_max_points = 100;  // evenly thinned beyond this (speed)
    double cylinder_normal_weight = 0.1;
    double cylinder_section_low_m = 0.5;  // stem section used for the cylinder
    double cylinder_section_high_m = 3.0;
    double max_lean_rad = 0.35;
    bool silhouette = true;  // single scans: also the silhouette width estimate (preferred)
    bool fit_all = false;    // also fit the cylinder when a silhouette or circle decides,
                             // and the circle when a silhouette does (then only reported;
                             // costs time)
};

struct PerceptionConfig {
    double intensity_threshold = std::numeric_limits<double>::quiet_NaN();  // NaN: no filter
    // Single scans: the returns the filter removes become evidence: the kept returns are
    // filtered and clustered as without them, and a cluster of every return whose removed
    // returns its geometry shows to be bark facing the sensor replaces the kept returns' pieces
    // there (detector.cpp, withEvidencePieces). Off by default: with it on, the rough stems'
    // band circle reads -1.6 cm (tests/test_perception_dbh_stages.py asks for 1.5), and on the
    // DBH 8-loop check one tree more per loop goes without a DBH on five loops (issue 15).
    bool intensity_as_evidence = false;
    GroundConfig ground;
    NormalFilterConfig filter;
    SegmentationConfig segmentation;
    DiameterConfig diameter;
    double ground_voxel_m = 0.25;  // ground points returned one per voxel (for ICP / maps)
    // Breast height (z, input frame) given by the user for every stem; NaN: from the local
    // ground, else from the stem's lowest points (see BreastHeightSource).
    double breast_height_z = std::numeric_limits<double>::quiet_NaN();
    // Map clouds in which the chain finds no stem (a cropped trunk, a breast-height slice, a
    // stem cut out of a plot, all without ground): every 3D cluster whose cross-section is a
    // circle becomes a stem. Points are thinned to this voxel first (bounded cost).
    double slice_voxel_m = 0.01;
    double slice_min_inlier_ratio = 0.5;  // of the band points within the circle's inlier gate
};

}  // namespace forestslam::perception
