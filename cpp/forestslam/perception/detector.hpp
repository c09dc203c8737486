// The whole per-scan chain: intensity filter -> ground -> adaptive normal filter -> coarse
// clusters (range image or 3D) -> adaptive DBSCAN -> SVD stem classification and merge ->
// local ground, breast-height centre and diameter. All in the sensor (input) frame.
#pragma once

#include <Eigen/Core>
#include <map>
#include <string>
#include <vector>

#include "forestslam/common/types.hpp"
#include "forestslam/perception/config.hpp"
#include "forestslam/perception/stems.hpp"

namespace forestslam::perception {

struct Detection {
    std::vector<Stem> stems;
    Points3 ground;                                 // ground points, one per ground voxel
    Eigen::Vector3d up = Eigen::Vector3d::UnitZ();  // ground normal used for the stem axes
    int input_points = 0, finite_points = 0, after_intensity = 0, ground_points = 0;
    int filtered_points = 0, coarse_clusters = 0, refined_clusters = 0;
    std::map<std::string, double> timing_ms;  // per stage, wall clock
    std::map<std::string, double> cpu_ms;     // per stage, CPU time of the calling thread
};

// `intensity` and `ring` are empty (size 0) or hold one value per point (std::invalid_argument
// otherwise). `scan_centred`: the points are around the
// sensor origin (single scans, TLS stations); false for accumulated maps (fixed-radius normals,
// no range limit, 3D clustering).
Detection detectStems(const Eigen::Ref<const Points3> &points,
                      const Eigen::Ref<const Eigen::VectorXd> &intensity,
                      const Eigen::Ref<const Eigen::VectorXi> &ring, const SensorGeometry &sensor,
                      bool scan_centred, const PerceptionConfig &options);

// Ground normal from ground points (PCA), or +z when there are too few or it tilts > 30 deg.
Eigen::Vector3d groundNormal(const Eigen::Ref<const Points3> &ground);

}  // namespace forestslam::perception
