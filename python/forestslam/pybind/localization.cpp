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

namespace lc = forestslam::localization;

using IntRows = Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor>;
using IntRows6 = Eigen::Matrix<int, Eigen::Dynamic, 6, Eigen::RowMajor>;

IntRows toRows(const std::vector<std::array<int, 3>> &v) {
    IntRows out(v.size(), 3);
    for (size_t i = 0; i < v.size(); ++i) out.row(i) << v[i][0], v[i][1], v[i][2];
    return out;
}

// The triangulation, the stars and the trunks, read-only.
void defineLocalizationResults(py::module_ &m) {
    py::class_<lc::Triangulation>(m, "Triangulation", "delaunay's result (read-only), T triangles.")
        .def_property_readonly(
            "triangles", [](const lc::Triangulation &t) { return toRows(t.triangles); },
            "(T,3) int32 counter-clockwise row indices")
        .def_property_readonly(
            "neighbours", [](const lc::Triangulation &t) { return toRows(t.neighbours); },
            "(T,3) int32 triangle across the edge opposite each vertex, -1 on the hull")
        .def_readonly("used_points", &lc::Triangulation::used_points,
                      "input rows that took part (finite, not a duplicate of an earlier row)");
    py::class_<lc::StarSet>(m, "StarSet", "triangle_stars' result (read-only), S stars.")
        .def_readonly("descriptors", &lc::StarSet::descriptors,
                      "(T,2) [area, squared perimeter] per triangle")
        .def_property_readonly(
            "centre",
            [](const lc::StarSet &set) {
                Eigen::VectorXi centre(set.stars.size());
                for (size_t i = 0; i < set.stars.size(); ++i) centre[i] = set.stars[i].centre;
                return centre;
            },
            "(S,) centre triangle")
        .def_property_readonly(
            "vertices",
            [](const lc::StarSet &set) {
                IntRows6 vertices(set.stars.size(), 6);
                for (size_t i = 0; i < set.stars.size(); ++i)
                    for (int k = 0; k < 6; ++k) vertices(i, k) = set.stars[i].vertices[k];
                return vertices;
            },
            "(S,6) centre v0 v1 v2 ccw from the shortest edge, then the apexes across v0v1, "
            "v1v2, v2v0")
        .def_property_readonly(
            "features", [](const lc::StarSet &set) { return set.features(); },
            "(S,8) [A0,l0,A1,l1,A2,l2,A3,l3]");
    py::class_<lc::Trunks>(m, "Trunks", "extract_trunks' result (read-only), K trunks.")
        .def_property_readonly(
            "xy", [](const lc::Trunks &t) { return Points2(t.xy); },
            "(K,2) mean xy per trunk cluster (a writable copy)")
        .def_readonly("sizes", &lc::Trunks::sizes, "points per cluster (list[int])")
        .def_readonly("z_min", &lc::Trunks::z_min, "(K,) lowest point of each cluster")
        .def_readonly("z_max", &lc::Trunks::z_max, "(K,) highest point of each cluster");
}

// Delaunay triangulation and triangle stars.
void defineTriangulation(py::module_ &m) {
    m.def(
        "delaunay",
        [](const Eigen::Ref<const Points2> &xy, double duplicate_tolerance) {
            const localization::Triangulation tri =
                localization::delaunayTriangulation(xy, duplicate_tolerance);
            return tri;
        },
        py::arg("xy"), py::arg("duplicate_tolerance") = 1e-6,
        "Delaunay triangulation of xy (N,2) float64 -> Triangulation. Non-finite and duplicate "
        "rows are skipped; collinear input gives no triangle.");

    m.def(
        "triangle_stars",
        [](const Eigen::Ref<const Points2> &xy) {
            const localization::Triangulation tri = localization::delaunayTriangulation(xy);
            return localization::buildStars(tri, xy);
        },
        py::arg("xy"), "Triangle stars of the Delaunay triangulation of xy (N,2) -> StarSet.");
}

void defineLocalizerConfig(py::module_ &m) {
    py::enum_<localization::Matcher>(m, "Matcher")
        .value("default", localization::Matcher::Default)
        .value("paper", localization::Matcher::Paper);

    py::class_<lc::GlobalLocalizerConfig> c(m, "GlobalLocalizerConfig");
    c.def(py::init<>());
    FS_FIELD(c, lc::GlobalLocalizerConfig, matcher);
    FS_FIELD(c, lc::GlobalLocalizerConfig, paper_angle_bin_rad);
    FS_FIELD(c, lc::GlobalLocalizerConfig, paper_translation_bin_m);
    FS_FIELD(c, lc::GlobalLocalizerConfig, candidates_per_star);
    FS_FIELD(c, lc::GlobalLocalizerConfig, max_feature_distance_m);
    FS_FIELD(c, lc::GlobalLocalizerConfig, rotation_ambiguity);
    FS_FIELD(c, lc::GlobalLocalizerConfig, edge_tolerance_m);
    FS_FIELD(c, lc::GlobalLocalizerConfig, inlier_gate_m);
    FS_FIELD(c, lc::GlobalLocalizerConfig, min_inliers);
    FS_FIELD(c, lc::GlobalLocalizerConfig, min_inliers_with_dbh);
    FS_FIELD(c, lc::GlobalLocalizerConfig, min_inlier_fraction);
    FS_FIELD(c, lc::GlobalLocalizerConfig, ambiguity_ratio);
    FS_FIELD(c, lc::GlobalLocalizerConfig, min_significance);
    FS_FIELD(c, lc::GlobalLocalizerConfig, closeness_evidence);
    FS_FIELD(c, lc::GlobalLocalizerConfig, seed_evidence);
    FS_FIELD(c, lc::GlobalLocalizerConfig, dbh_evidence);
    FS_FIELD(c, lc::GlobalLocalizerConfig, dbh_sigma_m);
    FS_FIELD(c, lc::GlobalLocalizerConfig, dbh_outlier_fraction);
    FS_FIELD(c, lc::GlobalLocalizerConfig, distinct_translation_m);
    FS_FIELD(c, lc::GlobalLocalizerConfig, distinct_yaw_rad);
    FS_FIELD(c, lc::GlobalLocalizerConfig, refine_iterations);
    FS_FIELD(c, lc::GlobalLocalizerConfig, min_sigma_m);
    FS_FIELD(c, lc::GlobalLocalizerConfig, duplicate_tolerance_m);
    FS_FIELD(c, lc::GlobalLocalizerConfig, skip_hull_stars);
    FS_FIELD(c, lc::GlobalLocalizerConfig, triangle_fallback);
    FS_FIELD(c, lc::GlobalLocalizerConfig, candidates_per_triangle);
    FS_FIELD(c, lc::GlobalLocalizerConfig, triangle_neighbours);
    FS_FIELD(c, lc::GlobalLocalizerConfig, max_query_trunks);
    FS_FIELD(c, lc::GlobalLocalizerConfig, max_fallback_trunks);
    FS_FIELD(c, lc::GlobalLocalizerConfig, max_fallback_matches);
}

// The answer of a global localization and its chance evidence.
void defineLocalizationResult(py::module_ &m) {
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
}

// The tree map with its star index, and trunks from a map cloud.
void defineTreeMap(py::module_ &m) {
    py::class_<localization::TreeMap>(m, "TreeMapIndex")
        .def(py::init<const Eigen::Ref<const Points2> &, double, const Eigen::VectorXd &>(),
             py::arg("xy"), py::arg("duplicate_tolerance_m") = 0.01,
             py::arg("dbh") = Eigen::VectorXd(),
             "Triangulate map trunks xy (M,2) float64 and index their triangle stars; dbh (M,) "
             "stem diameters in m (NaN unknown, empty none) for the DBH evidence.")
        .def("localize", &localization::TreeMap::localize, py::arg("local_xy"),
             py::arg("config") = localization::GlobalLocalizerConfig(),
             py::arg("local_dbh") = Eigen::VectorXd(), py::arg("observations") = Eigen::VectorXi(),
             py::call_guard<py::gil_scoped_release>(),
             "Pose of the local frame in the map from local trunks (K,2) and optionally their "
             "diameters (K,) and detection counts over aggregated frames (K,) -> "
             "GlobalLocalization.")
        .def_property_readonly("points", &localization::TreeMap::points, "(M,2) map trunks")
        .def_property_readonly(
            "triangles",
            [](const localization::TreeMap &t) { return toRows(t.triangulation().triangles); })
        .def_property_readonly(
            "neighbours",
            [](const localization::TreeMap &t) { return toRows(t.triangulation().neighbours); })
        .def_property_readonly(
            "stars", [](const localization::TreeMap &t) { return lc::StarSet(t.stars()); },
            "the map's triangle stars (StarSet)");
}

void defineTrunkExtraction(py::module_ &m) {
    py::class_<lc::TrunkExtractionConfig> t(m, "TrunkExtractionConfig");
    t.def(py::init<>());
    FS_FIELD(t, lc::TrunkExtractionConfig, voxel_m);
    FS_FIELD(t, lc::TrunkExtractionConfig, height_offset_m);
    FS_FIELD(t, lc::TrunkExtractionConfig, neighbour_radius_m);
    FS_FIELD(t, lc::TrunkExtractionConfig, cluster_tolerance_m);
    FS_FIELD(t, lc::TrunkExtractionConfig, min_cluster_points);
    FS_FIELD(t, lc::TrunkExtractionConfig, max_cluster_points);
    FS_FIELD(t, lc::TrunkExtractionConfig, ground_cell_m);
    FS_FIELD(t, lc::TrunkExtractionConfig, band_min_m);
    FS_FIELD(t, lc::TrunkExtractionConfig, band_max_m);
    FS_FIELD(t, lc::TrunkExtractionConfig, min_cluster_height_m);
    FS_FIELD(t, lc::TrunkExtractionConfig, max_cluster_radius_m);

    m.def(
        "extract_trunks",
        [](const Eigen::Ref<const Points3> &cloud,
           const localization::TrunkExtractionConfig &config) {
            py::gil_scoped_release release;
            return localization::extractTrunks(cloud, config);
        },
        py::arg("cloud"), py::arg("config") = localization::TrunkExtractionConfig(),
        "Trunk positions from a map cloud (N,3) float64 (Li et al. Algorithm 1) -> Trunks.");
}

}  // namespace

void define_localization(py::module_ &m) {
    defineLocalizationResults(m);
    defineTriangulation(m);
    defineLocalizerConfig(m);
    defineLocalizationResult(m);
    defineTreeMap(m);
    defineTrunkExtraction(m);
}

}  // namespace forestslam::python
