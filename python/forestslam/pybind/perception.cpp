#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <optional>
#include <stdexcept>
#include <string>

#include "bindings.hpp"
#include "forestslam/common/circle_fit.hpp"
#include "forestslam/perception/detector.hpp"
#include "forestslam/perception/preprocess.hpp"
#include "forestslam/perception/segmentation.hpp"
#include "forestslam/perception/stems.hpp"

namespace py = pybind11;

namespace forestslam::python {
namespace {

namespace pc = forestslam::perception;

// Every perception option struct as a typed class (filled by forestslam.odometry.bridge).
void defineSensorGeometry(py::module_ &m) {
    py::class_<pc::SensorGeometry> g(m, "SensorGeometry", "What perception needs of a sensor.");
    g.def(py::init<>());
    FS_FIELD(g, pc::SensorGeometry, has_range_image);
    FS_FIELD(g, pc::SensorGeometry, image_rows);
    FS_FIELD(g, pc::SensorGeometry, image_cols);
    FS_FIELD(g, pc::SensorGeometry, horizontal_fov_rad);
    FS_FIELD(g, pc::SensorGeometry, vertical_angles_rad);
    FS_FIELD(g, pc::SensorGeometry, theta_v_rad);
    FS_FIELD(g, pc::SensorGeometry, azimuth_step_rad);
}

// The options of the ground and normal filters.
void defineFilterOptions(py::module_ &m) {
    py::class_<pc::GroundConfig> gr(m, "GroundConfig");
    gr.def(py::init<>());
    FS_FIELD(gr, pc::GroundConfig, cell_size_m);
    FS_FIELD(gr, pc::GroundConfig, max_window_cells);
    FS_FIELD(gr, pc::GroundConfig, slope);
    FS_FIELD(gr, pc::GroundConfig, initial_distance_m);
    FS_FIELD(gr, pc::GroundConfig, max_distance_m);
    FS_FIELD(gr, pc::GroundConfig, base);
    FS_FIELD(gr, pc::GroundConfig, exponential);
    FS_FIELD(gr, pc::GroundConfig, cell_height_m);
    FS_FIELD(gr, pc::GroundConfig, min_component_cells);
    FS_FIELD(gr, pc::GroundConfig, max_range_m);

    py::class_<pc::NormalFilterConfig> f(m, "NormalFilterConfig");
    f.def(py::init<>());
    FS_FIELD(f, pc::NormalFilterConfig, adaptive);
    FS_FIELD(f, pc::NormalFilterConfig, ring_min_m);
    FS_FIELD(f, pc::NormalFilterConfig, ring_max_m);
    FS_FIELD(f, pc::NormalFilterConfig, rings);
    FS_FIELD(f, pc::NormalFilterConfig, radius_scale);
    FS_FIELD(f, pc::NormalFilterConfig, min_radius_m);
    FS_FIELD(f, pc::NormalFilterConfig, max_radius_m);
    FS_FIELD(f, pc::NormalFilterConfig, fixed_radius_m);
    FS_FIELD(f, pc::NormalFilterConfig, max_normal_angle_rad);
    FS_FIELD(f, pc::NormalFilterConfig, min_neighbours);
    FS_FIELD(f, pc::NormalFilterConfig, max_neighbours);
    FS_FIELD(f, pc::NormalFilterConfig, min_height_m);
    FS_FIELD(f, pc::NormalFilterConfig, max_height_m);
    FS_FIELD(f, pc::NormalFilterConfig, voxel_m);
    FS_FIELD(f, pc::NormalFilterConfig, map_voxel_m);
}

// The options of segmentation and DBH, and the chain's options holding all of them.
void defineStemOptions(py::module_ &m) {
    py::class_<pc::SegmentationConfig> s(m, "SegmentationConfig");
    s.def(py::init<>());
    FS_FIELD(s, pc::SegmentationConfig, block_cols);
    FS_FIELD(s, pc::SegmentationConfig, beta_min_rad);
    FS_FIELD(s, pc::SegmentationConfig, max_neighbour_gap_m);
    FS_FIELD(s, pc::SegmentationConfig, max_pixel_gap);
    FS_FIELD(s, pc::SegmentationConfig, max_gap_m);
    FS_FIELD(s, pc::SegmentationConfig, min_votes);
    FS_FIELD(s, pc::SegmentationConfig, euclidean_tolerance_m);
    FS_FIELD(s, pc::SegmentationConfig, dbscan_k);
    FS_FIELD(s, pc::SegmentationConfig, dbscan_min_neighbours);
    FS_FIELD(s, pc::SegmentationConfig, dbscan_min_eps_m);
    FS_FIELD(s, pc::SegmentationConfig, dbscan_max_eps_m);
    FS_FIELD(s, pc::SegmentationConfig, map_dbscan_eps_m);
    FS_FIELD(s, pc::SegmentationConfig, min_points);
    FS_FIELD(s, pc::SegmentationConfig, min_length_m);
    FS_FIELD(s, pc::SegmentationConfig, max_axis_angle_rad);
    FS_FIELD(s, pc::SegmentationConfig, min_sv_ratio);
    FS_FIELD(s, pc::SegmentationConfig, max_width_m);
    FS_FIELD(s, pc::SegmentationConfig, merge_xy_m);
    FS_FIELD(s, pc::SegmentationConfig, max_range_m);
    FS_FIELD(s, pc::SegmentationConfig, ground_search_m);

    py::class_<pc::DiameterConfig> d(m, "DiameterConfig");
    d.def(py::init<>());
    FS_FIELD(d, pc::DiameterConfig, band_low_m);
    FS_FIELD(d, pc::DiameterConfig, band_high_m);
    FS_FIELD(d, pc::DiameterConfig, band_max_half_m);
    FS_FIELD(d, pc::DiameterConfig, min_band_points);
    FS_FIELD(d, pc::DiameterConfig, min_radius_m);
    FS_FIELD(d, pc::DiameterConfig, max_radius_m);
    FS_FIELD(d, pc::DiameterConfig, inlier_threshold_m);
    FS_FIELD(d, pc::DiameterConfig, min_arc_coverage);
    FS_FIELD(d, pc::DiameterConfig, map_min_arc_coverage);
    FS_FIELD(d, pc::DiameterConfig, cylinder_iterations);
    FS_FIELD(d, pc::DiameterConfig, cylinder_max_points);
    FS_FIELD(d, pc::DiameterConfig, cylinder_normal_weight);
    FS_FIELD(d, pc::DiameterConfig, cylinder_section_low_m);
    FS_FIELD(d, pc::DiameterConfig, cylinder_section_high_m);
    FS_FIELD(d, pc::DiameterConfig, max_lean_rad);
    FS_FIELD(d, pc::DiameterConfig, silhouette);
    FS_FIELD(d, pc::DiameterConfig, fit_all);

    py::class_<pc::PerceptionConfig> p(m, "PerceptionConfig",
                                       "intensity_threshold NaN: no intensity filter.");
    p.def(py::init<>());
    FS_FIELD(p, pc::PerceptionConfig, intensity_threshold);
    FS_FIELD(p, pc::PerceptionConfig, intensity_as_evidence);
    FS_FIELD(p, pc::PerceptionConfig, ground_voxel_m);
    FS_FIELD(p, pc::PerceptionConfig, breast_height_z);
    FS_FIELD(p, pc::PerceptionConfig, ground);
    FS_FIELD(p, pc::PerceptionConfig, filter);
    FS_FIELD(p, pc::PerceptionConfig, segmentation);
    FS_FIELD(p, pc::PerceptionConfig, diameter);
    FS_FIELD(p, pc::PerceptionConfig, slice_voxel_m);
    FS_FIELD(p, pc::PerceptionConfig, slice_min_inlier_ratio);
}

py::list clustersList(const pc::Clusters &c) {
    py::list out;
    for (const auto &rows : c)
        out.append(py::array_t<int>(static_cast<py::ssize_t>(rows.size()), rows.data()));
    return out;
}

std::vector<int> toRows(const py::array_t<int, py::array::c_style | py::array::forcecast> &a) {
    return std::vector<int>(a.data(), a.data() + a.size());
}

}  // namespace

namespace {

// Per-stem column of a detection, (K,) or (K,n) with n = the size of what `get` returns.
template <typename T, typename Get>
py::array_t<T> stemColumn(const perception::Detection &det, int n, Get get) {
    const auto k = static_cast<py::ssize_t>(det.stems.size());
    py::array_t<T> out =
        n == 1 ? py::array_t<T>(k) : py::array_t<T>(std::vector<py::ssize_t>{k, n});
    T *data = out.mutable_data();
    for (size_t i = 0; i < det.stems.size(); ++i) get(det.stems[i], data + i * n);
    return out;
}

const char *methodName(int method) {
    return method == 1 ? "circle" : method == 2 ? "cylinder" : method == 3 ? "silhouette" : "none";
}

// A stem's diameter estimates, read-only (perception_estimate_diameter, Detection.diameters).
void defineDiameterResults(py::module_ &m) {
    py::class_<pc::DiameterFit>(
        m, "DiameterFit",
        "One diameter estimate and its quality on the breast-height band (read-only).")
        .def_readonly("valid", &pc::DiameterFit::valid, "accepted by the DiameterConfig gates")
        .def_readonly("radius", &pc::DiameterFit::radius, "m")
        .def_readonly("centre", &pc::DiameterFit::centre, "(3,) at breast height")
        .def_readonly("axis", &pc::DiameterFit::axis, "(3,) unit")
        .def_readonly("inliers", &pc::DiameterFit::inliers)
        .def_readonly("rms_m", &pc::DiameterFit::rms_m, "RMS of the inlier residuals")
        .def_readonly("arc_coverage", &pc::DiameterFit::arc_coverage, "in [0, 1]")
        .def_readonly("score", &pc::DiameterFit::score,
                      "inlier ratio * arc coverage / max(rms, 5 mm): larger is better")
        .def_readonly("radius_std", &pc::DiameterFit::radius_std,
                      "expected error (1 sigma) of the radius, m; NaN when unknown")
        .def_readonly("multi_object_lines", &pc::DiameterFit::multi_object_lines,
                      "silhouette: scan lines left out as spanning more than one object");

    py::class_<pc::StemDiameter>(
        m, "StemDiameter",
        "Diameter of one stem (read-only): the circle (band), cylinder (PCL SAC) and silhouette "
        "estimates, the one chosen and its DBH.")
        .def_readonly("circle", &pc::StemDiameter::circle,
                      "not fitted (valid False) when an accepted silhouette decides, unless "
                      "DiameterConfig.fit_all")
        .def_readonly("cylinder", &pc::StemDiameter::cylinder,
                      "not fitted (valid False) when an accepted silhouette or band circle "
                      "decides, unless DiameterConfig.fit_all")
        .def_readonly("silhouette", &pc::StemDiameter::silhouette)
        .def_property_readonly(
            "method", [](const pc::StemDiameter &d) { return methodName(d.method); },
            "circle, cylinder, silhouette or none")
        .def_readonly("dbh", &pc::StemDiameter::dbh, "m; NaN when no estimate is accepted")
        .def_readonly("dbh_std", &pc::StemDiameter::dbh_std, "expected error (1 sigma), m")
        .def_readonly("centre", &pc::StemDiameter::centre, "(3,)")
        .def_readonly("band_points", &pc::StemDiameter::band_points);
}

// The stems' per-stem arrays of a Detection (made when read).
template <typename C>
void addStemArrays(C &c) {
    using Det = pc::Detection;
    using S = pc::Stem;
    c.def_property_readonly(
         "xy",
         [](const Det &d) {
             return stemColumn<double>(
                 d, 2, [](const S &s, double *o) { o[0] = s.breast.x(), o[1] = s.breast.y(); });
         },
         "(K,2) breast-height centres")
        .def_property_readonly(
            "z",
            [](const Det &d) {
                return stemColumn<double>(d, 1, [](const S &s, double *o) { *o = s.breast.z(); });
            },
            "(K,) breast height")
        .def_property_readonly(
            "dbh",
            [](const Det &d) {
                return stemColumn<double>(d, 1, [](const S &s, double *o) { *o = s.diameter.dbh; });
            },
            "(K,) m, NaN where no diameter was accepted")
        .def_property_readonly(
            "base_z",
            [](const Det &d) {
                return stemColumn<double>(d, 1, [](const S &s, double *o) { *o = s.base_z; });
            },
            "(K,) local ground height")
        .def_property_readonly(
            "mean",
            [](const Det &d) {
                return stemColumn<double>(d, 3, [](const S &s, double *o) {
                    for (int c = 0; c < 3; ++c) o[c] = s.shape.mean(c);
                });
            },
            "(K,3) mean of the stem points")
        .def_property_readonly(
            "cov",
            [](const Det &d) {
                return stemColumn<double>(d, 9, [](const S &s, double *o) {
                    for (int r = 0; r < 3; ++r)
                        for (int c = 0; c < 3; ++c) o[3 * r + c] = s.shape.cov(r, c);
                });
            },
            "(K,9) row-major 3x3 covariance of the stem points")
        .def_property_readonly(
            "axis",
            [](const Det &d) {
                return stemColumn<double>(d, 3, [](const S &s, double *o) {
                    for (int c = 0; c < 3; ++c) o[c] = s.shape.axis(c);
                });
            },
            "(K,3) principal axis, unit, pointing up");
}

// Their breast-height flags, points and diameters, and the detection's totals.
template <typename C>
void addStemListsAndTotals(C &c) {
    using Det = pc::Detection;
    using S = pc::Stem;
    c.def_property_readonly(
         "ground_found",
         [](const Det &d) {
             return stemColumn<int>(d, 1, [](const S &s, int *o) { *o = s.ground_found; });
         },
         "(K,) 1 where base_z is the local ground, 0 where the stem's lowest point")
        .def_property_readonly(
            "breast_source",
            [](const Det &d) {
                return stemColumn<int>(
                    d, 1, [](const S &s, int *o) { *o = static_cast<int>(s.breast_source); });
            },
            "(K,) index into forestslam.perception.stems.BREAST_HEIGHT_SOURCES")
        .def_property_readonly(
            "points",
            [](const Det &d) {
                py::list out;
                for (const S &s : d.stems) out.append(py::cast(s.points));
                return out;
            },
            "list of the K stems' points (Mi,3)")
        .def_property_readonly(
            "diameters",
            [](const Det &d) {
                py::list out;
                for (const S &s : d.stems) out.append(py::cast(s.diameter));
                return out;
            },
            "list of the K stems' StemDiameter (copies)")
        // copies: an array viewing the detection would keep all of it (stem points) alive
        .def_property_readonly(
            "ground", [](const Det &d) { return Points3(d.ground); },
            "(G,3) ground points, one per ground voxel")
        .def_property_readonly(
            "up", [](const Det &d) { return Eigen::Vector3d(d.up); },
            "(3,) ground normal used for the stem axes")
        .def_readonly("timing", &Det::timing_ms, "wall-clock ms per stage")
        .def_readonly("cpu_ms", &Det::cpu_ms, "CPU ms of the calling thread per stage")
        .def_property_readonly(
            "counts",
            [](const Det &d) {
                py::dict c;
                c["input"] = d.input_points;
                c["after_intensity"] = d.after_intensity;
                c["finite"] = d.finite_points;
                c["ground"] = d.ground_points;
                c["filtered"] = d.filtered_points;
                c["coarse_clusters"] = d.coarse_clusters;
                c["refined_clusters"] = d.refined_clusters;
                return c;
            },
            "per-stage point / cluster counts")
        .def("__len__", [](const Det &d) { return d.stems.size(); });
}

// The stems of one detection, read-only, in the layout of forestslam.perception.Stems; the
// per-stem arrays are made when read (the odometry reads the diameters only when asked).
void defineDetection(py::module_ &m) {
    py::class_<pc::Detection> c(m, "Detection",
                                "The stems of one scan or cloud (read-only; perception_detect and "
                                "OdometryResult.stems). K stems, sensor / input frame.");
    addStemArrays(c);
    addStemListsAndTotals(c);
}

// Circle fits on their own (also used by the tree map, the evaluation and the TLS tree fits):
// the options as one typed class, the result read-only.
void defineCircleFitTypes(py::module_ &m) {
    py::class_<CircleFitConfig> c(m, "CircleFitConfig",
                                  "Options of fit_circle / fit_circle_rays (C++ defaults).");
    c.def(py::init<>());
    FS_FIELD(c, CircleFitConfig, inlier_threshold_m);
    FS_FIELD(c, CircleFitConfig, min_radius_m);
    FS_FIELD(c, CircleFitConfig, max_radius_m);
    FS_FIELD(c, CircleFitConfig, max_ransac_iterations);
    FS_FIELD(c, CircleFitConfig, refine_iterations);
    FS_FIELD(c, CircleFitConfig, arc_sectors);
    FS_FIELD(c, CircleFitConfig, seed);
    FS_FIELD(c, CircleFitConfig, lateral_sigma_m);
    FS_FIELD(c, CircleFitConfig, min_range_anisotropy);

    py::class_<CircleFit> f(m, "CircleFit",
                            "A 2D circle fit (read-only). Invalid (valid False, NaN centre and "
                            "radius) for < 3 finite points, collinear points or a radius outside "
                            "the bounds.");
    f.def_readonly("valid", &CircleFit::valid)
        .def_readonly("centre", &CircleFit::centre, "(2,)")
        .def_readonly("radius", &CircleFit::radius, "m")
        .def_readonly("inliers", &CircleFit::inliers, "points within the inlier threshold")
        .def_readonly("rms_m", &CircleFit::rms_m, "RMS of the inlier residuals")
        .def_readonly("arc_coverage", &CircleFit::arc_coverage,
                      "share of the angular sectors holding inliers, in [0, 1]")
        .def_readonly("inlier_indices", &CircleFit::inlier_indices, "rows of xy (list[int])")
        .def_readonly("covariance", &CircleFit::covariance,
                      "(3,3) of (centre x, centre y, radius) from the inliers, sigma^2 (J^T J)^-1 "
                      "with n - 3 degrees of freedom; infinite for < 4 inliers or a degenerate arc")
        .def_property_readonly("radius_std", &CircleFit::radiusStd,
                               "standard deviation (m) of the radius, sqrt(covariance[2, 2])")
        .def("__repr__", [](const CircleFit &x) {
            return "CircleFit(valid=" + std::string(x.valid ? "True" : "False") +
                   ", radius=" + std::to_string(x.radius) +
                   ", inliers=" + std::to_string(x.inliers) + ")";
        });
}

void defineCircleFits(py::module_ &m) {
    m.def(
        "fit_circle_rays",
        [](const Eigen::Ref<const Points2> &xy, const Eigen::Ref<const Points2> &origins,
           const CircleFitConfig &config, std::optional<Eigen::VectorXd> weights) {
            if (origins.rows() != xy.rows())
                throw std::invalid_argument("fit_circle_rays: origins must have one row per point");
            if (weights && weights->size() != xy.rows())
                throw std::invalid_argument("fit_circle_rays: weights must have one per point");
            py::gil_scoped_release release;
            return weights ? fitCircleRaysWeighted(xy, origins, *weights, config)
                           : fitCircleRays(xy, origins, config);
        },
        py::arg("xy"), py::arg("origins"), py::arg("config") = CircleFitConfig(),
        py::arg("weights") = py::none(),
        "Circle fit of points xy (N,2) measured from view origins (N,2) (sensor positions, same "
        "frame): the robust fit refined under range noise along each beam (unbiased on one-sided "
        "arcs, where fit_circle shrinks the circle). config: CircleFitConfig. weights (N,): "
        "each point counts that often (see fit_circle). Returns CircleFit.");
    m.def(
        "fit_circle",
        [](const Eigen::Ref<const Points2> &xy, const CircleFitConfig &config,
           std::optional<Eigen::VectorXd> weights) {
            if (weights && weights->size() != xy.rows())
                throw std::invalid_argument("fit_circle: weights must have one per point");
            py::gil_scoped_release release;
            return weights ? fitCircleWeighted(xy, *weights, config) : fitCircle(xy, config);
        },
        py::arg("xy"), py::arg("config") = CircleFitConfig(), py::arg("weights") = py::none(),
        "Robust circle fit (RANSAC + Taubin + Tukey-weighted geometric LM) of xy (N,2) float64;\n"
        "config: CircleFitConfig; weights (N,) finite, >= 0: each point counts that often\n"
        "(integer weights: the fit of the points repeated). Returns CircleFit (non-finite rows\n"
        "are ignored; inlier_indices are rows of xy).");
    m.def(
        "circle_arc_jackknife",
        [](const Eigen::Ref<const Points2> &xy, const Eigen::Ref<const Eigen::VectorXd> &weights,
           const Eigen::Vector2d &centre, double radius, int blocks,
           const CircleFitConfig &config) {
            py::gil_scoped_release release;
            return circleArcJackknife(xy, weights, centre, radius, blocks, config);
        },
        py::arg("xy"), py::arg("weights"), py::arg("centre"), py::arg("radius"), py::arg("blocks"),
        py::arg("config") = CircleFitConfig(),
        "Block-jackknife standard deviation (m) of the radius of the circle (centre (2,), radius)\n"
        "fitted to xy (N,2) with weights (N,): its inliers (config.inlier_threshold_m) split by\n"
        "angle into `blocks` runs, the circle refitted without each in turn (independent of the\n"
        "rows' order; inf for fewer than 2 * blocks inliers).");
    m.def(
        "fit_circle_algebraic",
        [](const Eigen::Ref<const Points2> &xy) { return fitCircleAlgebraic(xy); }, py::arg("xy"),
        "Plain Taubin algebraic circle fit of xy (N,2); returns CircleFit.");
}

// The whole per-scan perception chain.
void defineDetect(py::module_ &m) {
    m.def(
        "perception_detect",
        [](const Eigen::Ref<const Points3> &points, std::optional<Eigen::VectorXd> intensity,
           std::optional<Eigen::VectorXi> ring, const pc::SensorGeometry &g, bool scan_centred,
           const pc::PerceptionConfig &options) {
            const pc::PerceptionConfig o = options;  // a copy: used without the GIL
            const Eigen::VectorXd in = intensity ? *intensity : Eigen::VectorXd();
            const Eigen::VectorXi rg = ring ? *ring : Eigen::VectorXi();
            pc::Detection det;
            {
                py::gil_scoped_release release;
                det = pc::detectStems(points, in, rg, g, scan_centred, o);
            }
            return det;
        },
        py::arg("points"), py::arg("intensity"), py::arg("ring"), py::arg("sensor"),
        py::arg("scan_centred"), py::arg("options"),
        "Whole perception chain on points (N,3) (intensity (N,)|None, ring (N,)|None).\n"
        "sensor: SensorGeometry; options: PerceptionConfig. Returns Detection.");
}

// The filter stages' results, read-only.
void defineFilterResults(py::module_ &m) {
    py::class_<pc::ClusterShape>(m, "ClusterShape",
                                 "Shape of one cluster from the SVD of its centred points "
                                 "(read-only).")
        .def_readonly("mean", &pc::ClusterShape::mean, "(3,)")
        .def_readonly("cov", &pc::ClusterShape::cov, "(3,3)")
        .def_readonly("axis", &pc::ClusterShape::axis, "(3,) principal axis, pointing up")
        .def_readonly("singular", &pc::ClusterShape::singular,
                      "(3,) s0 >= s1 >= s2, square roots of the eigenvalues")
        .def_readonly("length", &pc::ClusterShape::length, "extent along the axis, m")
        .def_readonly("width", &pc::ClusterShape::width, "extent along the second axis, m")
        .def_readonly("axis_angle", &pc::ClusterShape::axis_angle, "angle to up, rad");
    py::class_<pc::GroundGrid>(m, "GroundGrid", "The ground filter's height grid (read-only).")
        .def_readonly("z", &pc::GroundGrid::z,
                      "(rows = y cells, cols = x cells) ground height, NaN where unknown")
        .def_readonly("origin", &pc::GroundGrid::origin,
                      "(2,) corner of cell (0, 0): it spans [origin, origin + cell) in x and y")
        .def_readonly("cell", &pc::GroundGrid::cell, "cell size, m");
    py::class_<pc::GroundSegmentation>(m, "GroundSegmentation",
                                       "perception_segment_ground's result (read-only).")
        .def_property_readonly(
            "is_ground",
            [](const pc::GroundSegmentation &g) {
                py::array_t<bool> mask(static_cast<py::ssize_t>(g.is_ground.size()));
                bool *out = mask.mutable_data();
                for (size_t i = 0; i < g.is_ground.size(); ++i) out[i] = g.is_ground[i] != 0;
                return mask;
            },
            "(N,) bool, one flag per input row")
        .def_readonly("grid", &pc::GroundSegmentation::grid, "GroundGrid")
        .def_readonly("ground_count", &pc::GroundSegmentation::ground_count);
    py::class_<pc::NormalFilterResult>(m, "NormalFilterResult",
                                       "perception_normal_filter's result (read-only).")
        .def_readonly("kept", &pc::NormalFilterResult::kept,
                      "rows of the input that pass (list[int])")
        .def_readonly("normals", &pc::NormalFilterResult::normals,
                      "(M,3) unit normals of the kept rows")
        .def_readonly("radius_per_ring", &pc::NormalFilterResult::radius_per_ring,
                      "search radius used per ring (one value in fixed mode)");
}

// Every stage of the chain on its own (debugging and the ablation): the filters ...
void defineFilterStages(py::module_ &m) {
    using IntArray = py::array_t<int, py::array::c_style | py::array::forcecast>;
    m.def(
        "perception_intensity_filter",
        [](const Eigen::VectorXd &intensity, double threshold) {
            return pc::intensityFilter(intensity, threshold, intensity.size());
        },
        py::arg("intensity"), py::arg("threshold"),
        "Rows (list[int]) with intensity <= threshold (all rows when threshold is NaN).");
    m.def(
        "perception_segment_ground",
        [](const Eigen::Ref<const Points3> &points, const pc::GroundConfig &options) {
            return pc::segmentGround(points, options);
        },
        py::arg("points"), py::arg("options"),
        "Approximate progressive morphological ground filter of points (N,3) -> "
        "GroundSegmentation.");
    m.def(
        "perception_normal_filter",
        [](const Eigen::Ref<const Points3> &points, const IntArray &candidates, double theta_v,
           const pc::NormalFilterConfig &options) {
            return pc::normalFilter(points, toRows(candidates), theta_v, options, nullptr);
        },
        py::arg("points"), py::arg("candidates"), py::arg("theta_v_rad"), py::arg("options"),
        "Adaptive ring-based normal filter over rows `candidates` of points (N,3) -> "
        "NormalFilterResult.");
}

// Clustering, stem classification and DBH of single clusters.
void defineClusterStages(py::module_ &m) {
    m.def(
        "perception_range_image_clusters",
        [](const Eigen::Ref<const Points3> &points, std::optional<Eigen::VectorXi> ring,
           const pc::SensorGeometry &g, const pc::SegmentationConfig &options, int min_size) {
            const Eigen::VectorXi rg = ring ? *ring : Eigen::VectorXi();
            const auto proj = pc::projectToRangeImage(points, rg, g);
            return clustersList(pc::rangeImageClusters(points, proj, g, options, min_size));
        },
        py::arg("points"), py::arg("ring"), py::arg("sensor"), py::arg("options"),
        py::arg("min_size") = 2, "Divide-and-merge range-image clusters: list of row arrays.");
    m.def(
        "perception_euclidean_clusters",
        [](const Eigen::Ref<const Points3> &points, double tolerance, int min_size) {
            return clustersList(pc::euclideanClusters(points, tolerance, min_size));
        },
        py::arg("points"), py::arg("tolerance_m"), py::arg("min_size") = 2,
        "3D Euclidean clusters of points (N,3): list of row arrays.");
    m.def(
        "perception_dbscan",
        [](const Eigen::Ref<const Points3> &points, double eps, int min_neighbours) {
            std::vector<int> rows(static_cast<size_t>(points.rows()));
            for (size_t i = 0; i < rows.size(); ++i) rows[i] = static_cast<int>(i);
            return clustersList(pc::dbscan(points, rows, eps, min_neighbours));
        },
        py::arg("points"), py::arg("eps"), py::arg("min_neighbours") = 2,
        "DBSCAN of points (N,3): list of row arrays (noise dropped).");
    m.def(
        "perception_cluster_shape",
        [](const Eigen::Ref<const Points3> &points, const Eigen::Vector3d &up) {
            std::vector<int> rows(static_cast<size_t>(points.rows()));
            for (size_t i = 0; i < rows.size(); ++i) rows[i] = static_cast<int>(i);
            return pc::clusterShape(points, rows, up);
        },
        py::arg("points"), py::arg("up"),
        "SVD shape of one cluster (M,3) -> ClusterShape (axis pointing along `up`).");
    m.def(
        "perception_is_stem",
        [](const pc::ClusterShape &shape, int count, const pc::SegmentationConfig &options) {
            return pc::isStem(shape, count, options);
        },
        py::arg("shape"), py::arg("count"), py::arg("options"),
        "The stem decision on a cluster of `count` points of this shape (SegmentationConfig: "
        "count, length, angle to up, singular-value ratio, width).");
    m.def(
        "perception_estimate_diameter",
        [](const Eigen::Ref<const Points3> &points, std::optional<Points3> normals, double base_z,
           const Eigen::Vector3d &up, const pc::DiameterConfig &options) {
            const Points3 n = normals ? *normals : Points3(0, 3);
            return pc::estimateDiameter(points, n, base_z, up, options);
        },
        py::arg("points"), py::arg("normals"), py::arg("base_z"), py::arg("up"), py::arg("options"),
        "Diameter of one stem (M,3) (normals (M,3)|None) above ground height base_z: "
        "StemDiameter (dbh NaN if none accepted).");
}

}  // namespace

void define_perception(py::module_ &m) {
    defineSensorGeometry(m);
    defineFilterOptions(m);
    defineStemOptions(m);
    defineCircleFitTypes(m);
    defineCircleFits(m);
    defineDiameterResults(m);
    defineDetection(m);
    defineFilterResults(m);
    defineDetect(m);
    defineFilterStages(m);
    defineClusterStages(m);
}

}  // namespace forestslam::python
