// Bindings of the global localization core: Delaunay triangulation, triangle stars, the tree
// map with its star index, and trunk extraction from a map cloud.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "bindings.hpp"
#include "forestslam/localization/delaunay.hpp"
#include "forestslam/localization/global_localizer.hpp"
#include "forestslam/localization/triangle_star.hpp"
#include "forestslam/localization/trunk_extraction.hpp"

namespace py = pybind11;

namespace forestslam::python {
namespace {

using IntRows = Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor>;
using IntRows6 = Eigen::Matrix<int, Eigen::Dynamic, 6, Eigen::RowMajor>;

IntRows toRows(const std::vector<std::array<int, 3>> &v) {
    IntRows out(v.size(), 3);
    for (size_t i = 0; i < v.size(); ++i) out.row(i) << v[i][0], v[i][1], v[i][2];
    return out;
}

py::dict starsToDict(const localization::StarSet &set) {
    IntRows6 vertices(set.stars.size(), 6);
    Eigen::VectorXi centre(set.stars.size());
    for (size_t i = 0; i < set.stars.size(); ++i) {
        for (int k = 0; k < 6; ++k) vertices(i, k) = set.stars[i].vertices[k];
        centre[i] = set.stars[i].centre;
    }
    py::dict d;
    d["descriptors"] = set.descriptors;
    d["centre"] = centre;
    d["vertices"] = vertices;
    d["features"] = set.features();
    return d;
}

}  // namespace

void define_localization(py::module_ &m) {
    m.def(
        "delaunay",
        [](const Eigen::Ref<const Points2> &xy, double duplicate_tolerance) {
            const localization::Triangulation tri =
                localization::delaunayTriangulation(xy, duplicate_tolerance);
            return py::make_tuple(toRows(tri.triangles), toRows(tri.neighbours));
        },
        py::arg("xy"), py::arg("duplicate_tolerance") = 1e-6,
        "Delaunay triangulation of xy (N,2) float64 -> (triangles (T,3) int32 counter-clockwise "
        "row indices, neighbours (T,3) int32: triangle across the edge opposite each vertex, -1 "
        "on the hull). Non-finite and duplicate rows are skipped; collinear input gives T = 0.");

    m.def(
        "triangle_stars",
        [](const Eigen::Ref<const Points2> &xy) {
            const localization::Triangulation tri = localization::delaunayTriangulation(xy);
            return starsToDict(localization::buildStars(tri, xy));
        },
        py::arg("xy"),
        "Triangle stars of the Delaunay triangulation of xy (N,2) -> dict: descriptors (T,2) "
        "[area, squared perimeter] per triangle, centre (S,) centre triangle, vertices (S,6) "
        "(centre v0 v1 v2 ccw from the shortest edge, then the apexes across v0v1, v1v2, v2v0), "
        "features (S,8) [A0,l0,A1,l1,A2,l2,A3,l3].");

    py::enum_<localization::Matcher>(m, "Matcher")
        .value("default", localization::Matcher::Default)
        .value("paper", localization::Matcher::Paper);

    py::class_<localization::GlobalLocalizerConfig>(m, "GlobalLocalizerConfig")
        .def(py::init<>())
        .def_readwrite("matcher", &localization::GlobalLocalizerConfig::matcher)
        .def_readwrite("paper_angle_bin_rad",
                       &localization::GlobalLocalizerConfig::paper_angle_bin_rad)
        .def_readwrite("paper_translation_bin_m",
                       &localization::GlobalLocalizerConfig::paper_translation_bin_m)
        .def_readwrite("candidates_per_star",
                       &localization::GlobalLocalizerConfig::candidates_per_star)
        .def_readwrite("max_feature_distance_m",
                       &localization::GlobalLocalizerConfig::max_feature_distance_m)
        .def_readwrite("rotation_ambiguity",
                       &localization::GlobalLocalizerConfig::rotation_ambiguity)
        .def_readwrite("edge_tolerance_m", &localization::GlobalLocalizerConfig::edge_tolerance_m)
        .def_readwrite("inlier_gate_m", &localization::GlobalLocalizerConfig::inlier_gate_m)
        .def_readwrite("min_inliers", &localization::GlobalLocalizerConfig::min_inliers)
        .def_readwrite("min_inlier_fraction",
                       &localization::GlobalLocalizerConfig::min_inlier_fraction)
        .def_readwrite("ambiguity_ratio", &localization::GlobalLocalizerConfig::ambiguity_ratio)
        .def_readwrite("min_significance", &localization::GlobalLocalizerConfig::min_significance)
        .def_readwrite("closeness_evidence",
                       &localization::GlobalLocalizerConfig::closeness_evidence)
        .def_readwrite("seed_evidence", &localization::GlobalLocalizerConfig::seed_evidence)
        .def_readwrite("dbh_evidence", &localization::GlobalLocalizerConfig::dbh_evidence)
        .def_readwrite("dbh_resolution_m", &localization::GlobalLocalizerConfig::dbh_resolution_m)
        .def_readwrite("distinct_translation_m",
                       &localization::GlobalLocalizerConfig::distinct_translation_m)
        .def_readwrite("distinct_yaw_rad", &localization::GlobalLocalizerConfig::distinct_yaw_rad)
        .def_readwrite("refine_iterations", &localization::GlobalLocalizerConfig::refine_iterations)
        .def_readwrite("min_sigma_m", &localization::GlobalLocalizerConfig::min_sigma_m)
        .def_readwrite("duplicate_tolerance_m",
                       &localization::GlobalLocalizerConfig::duplicate_tolerance_m)
        .def_readwrite("skip_hull_stars", &localization::GlobalLocalizerConfig::skip_hull_stars)
        .def_readwrite("triangle_fallback", &localization::GlobalLocalizerConfig::triangle_fallback)
        .def_readwrite("candidates_per_triangle",
                       &localization::GlobalLocalizerConfig::candidates_per_triangle)
        .def_readwrite("triangle_neighbours",
                       &localization::GlobalLocalizerConfig::triangle_neighbours)
        .def_readwrite("max_query_trunks", &localization::GlobalLocalizerConfig::max_query_trunks)
        .def_readwrite("max_fallback_trunks",
                       &localization::GlobalLocalizerConfig::max_fallback_trunks)
        .def_readwrite("max_fallback_matches",
                       &localization::GlobalLocalizerConfig::max_fallback_matches);

    py::class_<localization::RunnerUp>(m, "RunnerUp")
        .def_readonly("exists", &localization::RunnerUp::exists)
        .def_readonly("x", &localization::RunnerUp::x)
        .def_readonly("y", &localization::RunnerUp::y)
        .def_readonly("yaw", &localization::RunnerUp::yaw)
        .def_readonly("inliers", &localization::RunnerUp::inliers)
        .def_readonly("significance", &localization::RunnerUp::significance);

    m.def("poisson_tail_log10", &localization::poissonTailLog10, py::arg("mu"), py::arg("k"),
          "-log10 P(X >= k) for X ~ Poisson(mu).");
    m.def(
        "chance_significance",
        [](int inliers, int trials, double expected, int seed_points, int hypotheses) {
            return localization::chanceEvidence(inliers, trials, expected, seed_points, hypotheses)
                .significance;
        },
        py::arg("inliers"), py::arg("trials"), py::arg("expected"), py::arg("seed_points"),
        py::arg("hypotheses"),
        "-log10(hypotheses * P(chance inliers >= inliers - seeds)) with the chance inliers "
        "Poisson around `expected` (summed over `trials` trunks, seeds removed pro rata).");

    py::class_<localization::GlobalLocalization>(m, "GlobalLocalization")
        .def_readonly("rejected", &localization::GlobalLocalization::rejected)
        .def_readonly("reason", &localization::GlobalLocalization::reason)
        .def_readonly("x", &localization::GlobalLocalization::x)
        .def_readonly("y", &localization::GlobalLocalization::y)
        .def_readonly("yaw", &localization::GlobalLocalization::yaw)
        .def_readonly("covariance", &localization::GlobalLocalization::covariance,
                      "(3,3) over x, y, yaw")
        .def_readonly("inliers", &localization::GlobalLocalization::inliers)
        .def_readonly("second_inliers", &localization::GlobalLocalization::second_inliers)
        .def_property_readonly(
            "stage",
            [](const localization::GlobalLocalization &r) {
                return std::string(localization::stageName(r.stage));
            },
            "'star', 'triangle' or '' (no hypothesis)")
        .def_readonly("significance", &localization::GlobalLocalization::significance)
        .def_readonly("expected_chance_inliers",
                      &localization::GlobalLocalization::expected_chance_inliers)
        .def_readonly("dbh_pairs", &localization::GlobalLocalization::dbh_pairs)
        .def_readonly("runner_up", &localization::GlobalLocalization::runner_up)
        .def_readonly("hypotheses", &localization::GlobalLocalization::hypotheses)
        .def_readonly("query_stars", &localization::GlobalLocalization::query_stars)
        .def_readonly("matched_triangles", &localization::GlobalLocalization::matched_triangles)
        .def_readonly("local_trunks", &localization::GlobalLocalization::local_trunks)
        .def_readonly("rms_m", &localization::GlobalLocalization::rms_m)
        .def_property_readonly(
            "matches",
            [](const localization::GlobalLocalization &r) {
                Eigen::Matrix<int, Eigen::Dynamic, 2, Eigen::RowMajor> out(r.matches.size(), 2);
                for (size_t i = 0; i < r.matches.size(); ++i)
                    out.row(i) << r.matches[i].first, r.matches[i].second;
                return out;
            },
            "(K,2) int32 inlier pairs (local row, map row)")
        .def("transform", &localization::GlobalLocalization::transform,
             "(3,3) homogeneous T_map_local");

    py::class_<localization::TreeMap>(m, "TreeMapIndex")
        .def(py::init<const Eigen::Ref<const Points2> &, double, const Eigen::VectorXd &>(),
             py::arg("xy"), py::arg("duplicate_tolerance_m") = 0.01,
             py::arg("dbh") = Eigen::VectorXd(),
             "Triangulate map trunks xy (M,2) float64 and index their triangle stars; dbh (M,) "
             "stem diameters in m (NaN unknown, empty none) for the DBH evidence.")
        .def("localize", &localization::TreeMap::localize, py::arg("local_xy"),
             py::arg("config") = localization::GlobalLocalizerConfig(),
             py::arg("local_dbh") = Eigen::VectorXd(), py::call_guard<py::gil_scoped_release>(),
             "Pose of the local frame in the map from local trunks (K,2) and optionally their "
             "diameters (K,) -> GlobalLocalization.")
        .def_property_readonly("points", &localization::TreeMap::points, "(M,2) map trunks")
        .def_property_readonly(
            "triangles",
            [](const localization::TreeMap &t) { return toRows(t.triangulation().triangles); })
        .def_property_readonly(
            "neighbours",
            [](const localization::TreeMap &t) { return toRows(t.triangulation().neighbours); })
        .def_property_readonly(
            "stars", [](const localization::TreeMap &t) { return starsToDict(t.stars()); });

    py::class_<localization::TrunkExtractionConfig>(m, "TrunkExtractionConfig")
        .def(py::init<>())
        .def_readwrite("voxel_m", &localization::TrunkExtractionConfig::voxel_m)
        .def_readwrite("height_offset_m", &localization::TrunkExtractionConfig::height_offset_m)
        .def_readwrite("neighbour_radius_m",
                       &localization::TrunkExtractionConfig::neighbour_radius_m)
        .def_readwrite("cluster_tolerance_m",
                       &localization::TrunkExtractionConfig::cluster_tolerance_m)
        .def_readwrite("min_cluster_points",
                       &localization::TrunkExtractionConfig::min_cluster_points)
        .def_readwrite("max_cluster_points",
                       &localization::TrunkExtractionConfig::max_cluster_points)
        .def_readwrite("ground_cell_m", &localization::TrunkExtractionConfig::ground_cell_m)
        .def_readwrite("band_min_m", &localization::TrunkExtractionConfig::band_min_m)
        .def_readwrite("band_max_m", &localization::TrunkExtractionConfig::band_max_m)
        .def_readwrite("min_cluster_height_m",
                       &localization::TrunkExtractionConfig::min_cluster_height_m)
        .def_readwrite("max_cluster_radius_m",
                       &localization::TrunkExtractionConfig::max_cluster_radius_m);

    m.def(
        "extract_trunks",
        [](const Eigen::Ref<const Points3> &cloud,
           const localization::TrunkExtractionConfig &config) {
            localization::Trunks t;
            {
                py::gil_scoped_release release;  // numpy results are built with the GIL held
                t = localization::extractTrunks(cloud, config);
            }
            Eigen::VectorXi sizes =
                Eigen::Map<const Eigen::VectorXi>(t.sizes.data(), t.sizes.size());
            return py::make_tuple(t.xy, sizes);
        },
        py::arg("cloud"), py::arg("config") = localization::TrunkExtractionConfig(),
        "Trunk positions from a map cloud (N,3) float64 (Li et al. Algorithm 1) -> (xy (K,2), "
        "points per trunk cluster (K,)).");
}

}  // namespace forestslam::python
