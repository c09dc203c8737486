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

// Set config fields from keyword arguments; unknown keys raise (typos must not pass silently).
template <typename Config>
void applyKwargs(Config &cfg, const py::dict &kwargs,
                 const std::vector<std::pair<const char *, double Config::*>> &doubles,
                 const std::vector<std::pair<const char *, int Config::*>> &ints) {
    for (const auto &item : kwargs) {
        const auto key = item.first.cast<std::string>();
        bool found = false;
        for (const auto &[name, member] : doubles) {
            if (key == name) cfg.*member = item.second.cast<double>(), found = true;
        }
        for (const auto &[name, member] : ints) {
            if (key == name) cfg.*member = item.second.cast<int>(), found = true;
        }
        if (!found) throw py::value_error("unknown option '" + key + "'");
    }
}

}  // namespace

void define_features(py::module_ &m) {
    m.def(
        "voxel_downsample",
        [](const Eigen::Ref<const Points3> &points, double voxel_m) {
            py::gil_scoped_release release;
            return features::voxelDownsample(points, voxel_m);
        },
        py::arg("points"), py::arg("voxel_m"),
        "Centroid per occupied voxel of points (N,3) -> (M,3); non-finite rows dropped.");

    m.def(
        "detect_dog_keypoints",
        [](const Eigen::Ref<const Points3> &points, const py::kwargs &kwargs) {
            features::DogKeypointsConfig cfg;
            using C = features::DogKeypointsConfig;
            applyKwargs(cfg, kwargs,
                        {{"voxel_m", &C::voxel_m},
                         {"sigma_small_m", &C::sigma_small_m},
                         {"sigma_large_m", &C::sigma_large_m},
                         {"nms_radius_m", &C::nms_radius_m},
                         {"bucket_m", &C::bucket_m}},
                        {{"outlier_neighbours", &C::outlier_neighbours},
                         {"min_neighbours", &C::min_neighbours},
                         {"max_keypoints", &C::max_keypoints}});
            features::DogKeypoints kp;
            {
                py::gil_scoped_release release;
                kp = features::detectDogKeypoints(points, cfg);
            }
            return py::make_tuple(kp.points, kp.response);
        },
        py::arg("points"),
        "3D difference-of-Gaussians keypoints of points (N,3) -> (keypoints (K,3), response "
        "(K,)). Options (keywords): voxel_m, outlier_neighbours, "
        "sigma_small_m, sigma_large_m, min_neighbours, nms_radius_m, bucket_m, max_keypoints.");

    m.def(
        "extract_virtual_features",
        [](const Eigen::Ref<const Points3> &points, std::optional<std::vector<std::uint16_t>> rings,
           const py::kwargs &kwargs) {
            features::VirtualFeaturesConfig cfg;
            using C = features::VirtualFeaturesConfig;
            applyKwargs(
                cfg, kwargs,
                {{"min_diameter_m", &C::min_diameter_m},
                 {"max_diameter_m", &C::max_diameter_m},
                 {"gap_m", &C::gap_m},
                 {"gap_range_ratio", &C::gap_range_ratio},
                 {"layer_step_m", &C::layer_step_m},
                 {"layer_thickness_m", &C::layer_thickness_m},
                 {"cell_m", &C::cell_m},
                 {"min_z_m", &C::min_z_m},
                 {"max_z_m", &C::max_z_m},
                 {"fit_inlier_m", &C::fit_inlier_m},
                 {"min_inlier_ratio", &C::min_inlier_ratio},
                 {"max_fit_rms_m", &C::max_fit_rms_m},
                 {"max_centre_shift_m", &C::max_centre_shift_m},
                 {"max_vertical_gap_m", &C::max_vertical_gap_m},
                 {"radius_tolerance_m", &C::radius_tolerance_m},
                 {"max_taper", &C::max_taper},
                 {"min_vertical_span_m", &C::min_vertical_span_m}},
                {{"min_cluster_points", &C::min_cluster_points}, {"min_levels", &C::min_levels}});
            if (rings && static_cast<Eigen::Index>(rings->size()) != points.rows()) {
                throw py::value_error("rings must have one entry per point");
            }
            features::VirtualFeatures vf;
            {
                py::gil_scoped_release release;
                vf = rings ? features::extractVirtualFeaturesRings(points, *rings, cfg)
                           : features::extractVirtualFeaturesLayers(points, cfg);
            }
            py::dict out;
            out["centres"] = vf.centres;
            out["radii"] = vf.radii;
            out["stem_ids"] = vf.stem_ids;
            out["levels"] = vf.levels;
            out["rms"] = vf.rms;
            out["stems"] = vf.stems;
            out["stem_radii"] = vf.stem_radii;
            return out;
        },
        py::arg("points"), py::arg("rings") = py::none(),
        "Stem-centre (virtual) features of points (N,3): per ring when rings (N,) uint16 is "
        "given, else per horizontal layer. -> dict centres (V,3), radii (V,), stem_ids (V,), "
        "levels (V,), rms (V,), stems (S,3) mean centre per stem, stem_radii (S,). Options as "
        "keywords (VirtualFeaturesConfig field names).");
}

}  // namespace forestslam::python
