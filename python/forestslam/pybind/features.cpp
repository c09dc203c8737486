// Feature bindings: voxel grid, DoG keypoints and stem-centre (virtual) features; their option
// structs as typed classes (config crosses into C++ one way).
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "bindings.hpp"
#include "forestslam/features/dog_keypoints.hpp"
#include "forestslam/features/virtual_features.hpp"
#include "forestslam/features/voxel_grid.hpp"

namespace py = pybind11;

namespace forestslam::python {
namespace {

namespace ft = forestslam::features;

void defineFeatureConfigs(py::module_ &m) {
    py::class_<ft::DogKeypointsConfig> d(m, "DogKeypointsConfig");
    d.def(py::init<>());
    FS_FIELD(d, ft::DogKeypointsConfig, voxel_m);
    FS_FIELD(d, ft::DogKeypointsConfig, outlier_neighbours);
    FS_FIELD(d, ft::DogKeypointsConfig, sigma_small_m);
    FS_FIELD(d, ft::DogKeypointsConfig, sigma_large_m);
    FS_FIELD(d, ft::DogKeypointsConfig, min_neighbours);
    FS_FIELD(d, ft::DogKeypointsConfig, nms_radius_m);
    FS_FIELD(d, ft::DogKeypointsConfig, bucket_m);
    FS_FIELD(d, ft::DogKeypointsConfig, max_keypoints);

    py::class_<ft::VirtualFeaturesConfig> v(m, "VirtualFeaturesConfig");
    v.def(py::init<>());
    FS_FIELD(v, ft::VirtualFeaturesConfig, min_diameter_m);
    FS_FIELD(v, ft::VirtualFeaturesConfig, max_diameter_m);
    FS_FIELD(v, ft::VirtualFeaturesConfig, gap_m);
    FS_FIELD(v, ft::VirtualFeaturesConfig, gap_range_ratio);
    FS_FIELD(v, ft::VirtualFeaturesConfig, layer_step_m);
    FS_FIELD(v, ft::VirtualFeaturesConfig, layer_thickness_m);
    FS_FIELD(v, ft::VirtualFeaturesConfig, cell_m);
    FS_FIELD(v, ft::VirtualFeaturesConfig, min_z_m);
    FS_FIELD(v, ft::VirtualFeaturesConfig, max_z_m);
    FS_FIELD(v, ft::VirtualFeaturesConfig, min_cluster_points);
    FS_FIELD(v, ft::VirtualFeaturesConfig, fit_inlier_m);
    FS_FIELD(v, ft::VirtualFeaturesConfig, min_inlier_ratio);
    FS_FIELD(v, ft::VirtualFeaturesConfig, max_fit_rms_m);
    FS_FIELD(v, ft::VirtualFeaturesConfig, max_centre_shift_m);
    FS_FIELD(v, ft::VirtualFeaturesConfig, max_vertical_gap_m);
    FS_FIELD(v, ft::VirtualFeaturesConfig, radius_tolerance_m);
    FS_FIELD(v, ft::VirtualFeaturesConfig, max_taper);
    FS_FIELD(v, ft::VirtualFeaturesConfig, min_levels);
    FS_FIELD(v, ft::VirtualFeaturesConfig, min_vertical_span_m);
}

// extract_virtual_features' and detect_dog_keypoints' results, read-only.
void defineVirtualFeatures(py::module_ &m) {
    py::class_<ft::DogKeypoints>(m, "DogKeypoints",
                                 "detect_dog_keypoints' result (read-only), K keypoints.")
        .def_property_readonly(
            "points", [](const ft::DogKeypoints &k) { return Points3(k.points); }, "(K,3)")
        .def_property_readonly(
            "response", [](const ft::DogKeypoints &k) { return Eigen::VectorXd(k.response); },
            "(K,) |smoothed_small - smoothed_large| in metres");
    using V = ft::VirtualFeatures;
    // Copies, writable: the TLS pipeline moves its features (deskew, in-sweep motion).
    py::class_<V>(m, "VirtualFeatures",
                  "Stem-centre (virtual) features of a cloud (read-only): V circle centres of "
                  "rings or layers and S stems they belong to.")
        .def_property_readonly(
            "centres", [](const V &v) { return Points3(v.centres); },
            "(V,3) circle centre (x, y) at the cluster's mean z")
        .def_property_readonly(
            "radii", [](const V &v) { return Eigen::VectorXd(v.radii); }, "(V,)")
        .def_property_readonly(
            "stem_ids", [](const V &v) { return Eigen::VectorXi(v.stem_ids); },
            "(V,) 0..S-1, centres of one stem share an id")
        .def_property_readonly(
            "levels", [](const V &v) { return Eigen::VectorXi(v.levels); },
            "(V,) ring number or layer index")
        .def_property_readonly(
            "rms", [](const V &v) { return Eigen::VectorXd(v.rms); },
            "(V,) circle-fit RMS residual (m)")
        .def_property_readonly(
            "stems", [](const V &v) { return Points3(v.stems); }, "(S,3) per stem: mean centre")
        .def_property_readonly(
            "stem_radii", [](const V &v) { return Eigen::VectorXd(v.stem_radii); },
            "(S,) median radius");
}

void defineFeatureFunctions(py::module_ &m) {
    m.def(
        "voxel_downsample",
        [](const Eigen::Ref<const Points3> &points, double voxel_m) {
            py::gil_scoped_release release;
            return ft::voxelDownsample(points, voxel_m);
        },
        py::arg("points"), py::arg("voxel_m"),
        "Centroid per occupied voxel of points (N,3) -> (M,3); non-finite rows dropped.");

    py::class_<ft::VoxelGroups>(m, "VoxelGroups",
                                "Points grouped by voxel, the voxels in the order of their cells")
        .def_readonly("order", &ft::VoxelGroups::order, "(N,) points, voxel by voxel")
        .def_readonly("start", &ft::VoxelGroups::start, "(M,) first entry of each voxel in order")
        .def_readonly("inverse", &ft::VoxelGroups::inverse, "(N,) voxel of each point");
    m.def(
        "group_by_voxel",
        [](const Eigen::Ref<const Points3> &points, const Eigen::Vector3d &origin, double voxel_m) {
            py::gil_scoped_release release;
            return ft::groupByVoxel(points, origin, voxel_m);
        },
        py::arg("points"), py::arg("origin"), py::arg("voxel_m"),
        "Points (N,3) grouped by the voxel of floor((p - origin) / voxel_m), voxels in the order "
        "of their cells (x, then y, then z); ValueError beyond 2^21 voxels along an axis.");

    m.def(
        "detect_dog_keypoints",
        [](const Eigen::Ref<const Points3> &points, const ft::DogKeypointsConfig &config) {
            const ft::DogKeypointsConfig cfg = config;  // a copy: used without the GIL
            ft::DogKeypoints kp;
            {
                py::gil_scoped_release release;
                kp = ft::detectDogKeypoints(points, cfg);
            }
            return kp;
        },
        py::arg("points"), py::arg("config") = ft::DogKeypointsConfig(),
        "3D difference-of-Gaussians keypoints of points (N,3) -> DogKeypoints. config: "
        "DogKeypointsConfig.");

    m.def(
        "extract_virtual_features",
        [](const Eigen::Ref<const Points3> &points, std::optional<std::vector<std::uint16_t>> rings,
           const ft::VirtualFeaturesConfig &config) {
            if (rings && static_cast<Eigen::Index>(rings->size()) != points.rows()) {
                throw py::value_error("rings must have one entry per point");
            }
            const ft::VirtualFeaturesConfig cfg = config;
            ft::VirtualFeatures vf;
            {
                py::gil_scoped_release release;
                vf = rings ? ft::extractVirtualFeaturesRings(points, *rings, cfg)
                           : ft::extractVirtualFeaturesLayers(points, cfg);
            }
            return vf;
        },
        py::arg("points"), py::arg("rings") = py::none(),
        py::arg("config") = ft::VirtualFeaturesConfig(),
        "Stem-centre (virtual) features of points (N,3): per ring when rings (N,) uint16 is "
        "given, else per horizontal layer. -> VirtualFeatures. config: VirtualFeaturesConfig.");
}

}  // namespace

void define_features(py::module_ &m) {
    defineFeatureConfigs(m);
    defineVirtualFeatures(m);
    defineFeatureFunctions(m);
}

}  // namespace forestslam::python
