// Bindings of the forest ray caster (cpp/forestslam/sim): array conversion only.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "bindings.hpp"
#include "forestslam/sim/forest_scene.hpp"
#include "forestslam/sim/scan_synthesis.hpp"

namespace py = pybind11;

namespace forestslam::python {

namespace {

using RowMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

void requireCols(const RowMatrix &a, int cols, const char *name) {
    if (a.size() > 0 && a.cols() != cols)
        throw std::invalid_argument(std::string(name) + " must have " + std::to_string(cols) +
                                    " columns");
}

// Stem rows (K,12) or (K,18): x y z_base shear_x shear_y semi_a semi_b angle taper h_bottom
// height bark_amp [tree flare_amp flare_height sides poly_angle irregularity]. Bark and lobe
// phases are drawn from (seed, tree), so the segments of one tree share them.
std::vector<sim::Stem> makeStems(const RowMatrix &stems, uint64_t seed) {
    if (stems.size() > 0 && stems.cols() != 12 && stems.cols() != 18)
        throw std::invalid_argument("stems must have 12 or 18 columns");
    std::vector<sim::Stem> s(stems.rows());
    for (Eigen::Index i = 0; i < stems.rows(); ++i) {
        const auto r = stems.row(i);
        sim::Stem &st = s[i];
        st.base = {r(0), r(1), r(2)};
        st.shear = {r(3), r(4)};
        st.semi_a = r(5);
        st.semi_b = r(6);
        st.angle = r(7);
        st.taper = r(8);
        st.h_bottom = r(9);
        st.height = r(10);
        st.bark_amp = r(11);
        if (stems.cols() == 18) {
            if (!(std::isfinite(r(12)) && std::isfinite(r(15))))
                throw std::invalid_argument("stem tree id and sides must be finite");
            st.tree = static_cast<int32_t>(std::lround(r(12)));
            st.flare_amp = r(13);
            st.flare_height = r(14);
            st.sides = static_cast<int>(std::lround(r(15)));
            st.poly_angle = r(16);
            st.irregularity = r(17);
        }
        const uint64_t key = sim::mixKey(seed, static_cast<uint64_t>(st.tree >= 0 ? st.tree : i));
        for (int k = 0; k < 4; ++k)
            st.phase[k] = 2.0 * M_PI * sim::hashUniform(key, static_cast<uint64_t>(k));
        for (int k = 0; k < 3; ++k)
            st.lobe_phase[k] = 2.0 * M_PI * sim::hashUniform(key, static_cast<uint64_t>(4 + k));
    }
    return s;
}

sim::ForestScene makeScene(double x0, double y0, double cell, const Eigen::MatrixXd &z,
                           const RowMatrix &stems, const RowMatrix &cylinders,
                           const RowMatrix &foliage, uint64_t seed, double grid_cell_m) {
    requireCols(cylinders, 8, "cylinders");
    requireCols(foliage, 8, "foliage");
    sim::Heightfield terrain;
    if (z.size() > 0) terrain = sim::Heightfield(x0, y0, cell, z);
    std::vector<sim::Stem> s = makeStems(stems, seed);
    std::vector<sim::Cylinder> c(cylinders.rows());
    for (Eigen::Index i = 0; i < cylinders.rows(); ++i) {
        const auto r = cylinders.row(i);
        c[i] = {{r(0), r(1), r(2)}, {r(3), r(4), r(5)}, r(6), static_cast<uint8_t>(r(7))};
    }
    std::vector<sim::FoliageEllipsoid> f(foliage.rows());
    for (Eigen::Index i = 0; i < foliage.rows(); ++i) {
        const auto r = foliage.row(i);
        f[i] = {{r(0), r(1), r(2)}, {r(3), r(4), r(5)}, r(6), static_cast<uint8_t>(r(7))};
    }
    return sim::ForestScene(std::move(terrain), std::move(s), std::move(c), std::move(f),
                            grid_cell_m);
}

// The measurement model as a typed class: scalars as attributes, materials as a (7,4) array
// (median, sigma_return, sigma_object, incidence_exponent per surface class).
void defineScanModel(py::module_ &m) {
    py::class_<sim::ScanModel> c(m, "ScanModel", "The simulated sensor's measurement model.");
    c.def(py::init<>());
    FS_FIELD(c, sim::ScanModel, range_min_m);
    FS_FIELD(c, sim::ScanModel, range_max_m);
    FS_FIELD(c, sim::ScanModel, range_noise_m);
    FS_FIELD(c, sim::ScanModel, beam_divergence_rad);
    FS_FIELD(c, sim::ScanModel, dropout_rate);
    FS_FIELD(c, sim::ScanModel, grazing_cos);
    FS_FIELD(c, sim::ScanModel, far_fraction);
    FS_FIELD(c, sim::ScanModel, reference_range_m);
    FS_FIELD(c, sim::ScanModel, range_exponent);
    FS_FIELD(c, sim::ScanModel, near_range_m);
    FS_FIELD(c, sim::ScanModel, object_seed);
    c.def_property(
        "materials",
        [](const sim::ScanModel &model) {
            RowMatrix out(sim::kSurfaceCount, 4);
            for (int i = 0; i < sim::kSurfaceCount; ++i) {
                const sim::Material &mt = model.materials[i];
                out.row(i) << mt.median, mt.sigma_return, mt.sigma_object, mt.incidence_exponent;
            }
            return out;
        },
        [](sim::ScanModel &model, const RowMatrix &materials) {
            if (materials.rows() != sim::kSurfaceCount || materials.cols() != 4)
                throw std::invalid_argument("materials must be (7,4): one row per surface class");
            for (int i = 0; i < sim::kSurfaceCount; ++i)
                model.materials[i] = {materials(i, 0), materials(i, 1), materials(i, 2),
                                      materials(i, 3)};
        },
        "(7,4): median, sigma_return, sigma_object, incidence_exponent per surface class");
}

void checkScanModel(const sim::ScanModel &m) {
    if (!(m.range_noise_m >= 0 && m.beam_divergence_rad >= 0 && m.dropout_rate >= 0 &&
          m.dropout_rate < 1 && m.grazing_cos >= 0 && m.grazing_cos < 1 && m.far_fraction > 0 &&
          m.reference_range_m > 0 && m.near_range_m >= 0))
        throw std::invalid_argument("scan model values out of range");
}

// The scene: ray casting and the synthesis of one scan.
// The ray casts' results, read-only (their arrays are writable copies).
void defineSimResults(py::module_ &m) {
    using C = sim::CastResult;
    py::class_<C>(m, "CastResult", "SimScene.cast's result (read-only), N rays.")
        .def_property_readonly(
            "range", [](const C &r) { return Eigen::VectorXd(r.range); },
            "(N,) NaN where no return")
        .def_property_readonly(
            "surface", [](const C &r) { return decltype(r.surface)(r.surface); },
            "(N,) uint8 [0 none 1 ground 2 stem 3 branch 4 foliage 5 shrub 6 log]")
        .def_property_readonly(
            "object", [](const C &r) { return decltype(r.object)(r.object); },
            "(N,) int32 row in its table")
        .def_property_readonly(
            "cos_incidence", [](const C &r) { return Eigen::VectorXd(r.cos_incidence); }, "(N,)");
    using S = sim::SynthesizedScan;
    py::class_<S>(m, "SynthesizedScan", "SimScene.synthesize's result (read-only), K returns.")
        .def_property_readonly(
            "ray", [](const S &r) { return decltype(r.ray)(r.ray); },
            "(K,) int64 pattern rows kept, increasing")
        .def_property_readonly(
            "points", [](const S &r) { return Points3(r.points); },
            "(K,3) sensor frame at each ray's own time")
        .def_property_readonly(
            "intensity", [](const S &r) { return Eigen::VectorXf(r.intensity); }, "(K,) float32")
        .def_property_readonly(
            "surface", [](const S &r) { return decltype(r.surface)(r.surface); }, "(K,) uint8")
        .def_property_readonly(
            "object", [](const S &r) { return decltype(r.object)(r.object); }, "(K,) int32");
}

void defineSimScene(py::module_ &m) {
    py::class_<sim::ForestScene>(m, "SimScene",
                                 "Forest scene for the LiDAR simulator: heightfield terrain plus "
                                 "stems, cylinders and foliage volumes in a uniform XY grid.")
        .def(
            py::init(&makeScene), py::arg("x0"), py::arg("y0"), py::arg("cell"), py::arg("z"),
            py::arg("stems"), py::arg("cylinders"), py::arg("foliage"), py::arg("seed") = 0,
            py::arg("grid_cell_m") = 3.0,
            "z (ny+1, nx+1) terrain vertex heights at x0 + ix*cell, y0 + iy*cell (empty: no "
            "ground). stems (K,12) or (K,18): x y z_base shear_x shear_y semi_a semi_b angle taper "
            "h_bottom height bark_amp [tree flare_amp flare_height sides poly_angle "
            "irregularity] (semi-axes at 1.3 m; radius scale 1 - taper (h - 1.3); see "
            "sim::Stem; a stem's hits report its tree id as object when tree >= 0). "
            "cylinders (M,8): x0 y0 z0 x1 y1 z1 radius surface. foliage (F,8): cx cy cz rx ry rz "
            "sigma surface. seed: bark and lobe phases.")
        .def(
            "cast",
            [](const sim::ForestScene &scene, const Eigen::Ref<const Points3> &origins,
               const Eigen::Ref<const Points3> &dirs, double range_min, double range_max,
               uint64_t seed) {
                sim::CastResult r;
                {
                    py::gil_scoped_release release;
                    r = scene.castRays(origins, dirs, range_min, range_max, seed);
                }
                return r;
            },
            py::arg("origins"), py::arg("dirs"), py::arg("range_min"), py::arg("range_max"),
            py::arg("seed") = 0,
            "origins (G,3) with G dividing N (ray i starts at origin i // (N/G)), unit dirs (N,3) "
            "-> CastResult.")
        .def(
            "synthesize",
            [](const sim::ForestScene &scene, const Eigen::Ref<const Eigen::VectorXd> &knot_time,
               const Eigen::Ref<const sim::PoseRows> &knot_pose,
               const Eigen::Ref<const Eigen::VectorXd> &group_time,
               const Eigen::Ref<const sim::IndexVector> &group,
               const Eigen::Ref<const Points3> &local_dirs, const sim::ScanModel &scan_model,
               uint64_t cast_seed, uint64_t noise_seed) {
                checkScanModel(scan_model);
                const sim::ScanModel model = scan_model;  // a copy: used without the GIL
                sim::SynthesizedScan r;
                {
                    py::gil_scoped_release release;
                    r = sim::synthesizeScan(scene, knot_time, knot_pose, group_time, group,
                                            local_dirs, model, cast_seed, noise_seed);
                }
                return r;
            },
            py::arg("knot_time"), py::arg("knot_pose"), py::arg("group_time"), py::arg("group"),
            py::arg("local_dirs"), py::arg("model"), py::arg("cast_seed"), py::arg("noise_seed"),
            "One scan: knot_time (M,) increasing with knot_pose (M,16) row-major T_world_sensor, "
            "interpolated to group_time (G,); ray i fires local_dirs[i] (N,3, sensor frame) from "
            "the pose of group[i] (N,) int64. model: ScanModel. -> SynthesizedScan. Dropouts, "
            "range and intensity noise are drawn from noise_seed, foliage from cast_seed.")
        .def(
            "height_at",
            [](const sim::ForestScene &scene, const Eigen::Ref<const Points2> &xy) {
                Eigen::VectorXd z(xy.rows());
                for (Eigen::Index i = 0; i < xy.rows(); ++i)
                    z[i] = scene.terrain().heightAt(xy(i, 0), xy(i, 1));
                return z;
            },
            py::arg("xy"), "Terrain height at xy (N,2) -> (N,), NaN outside the heightfield.");
}

void defineStemSections(py::module_ &m) {
    m.def(
        "sim_stem_sections",
        [](const RowMatrix &stems, uint64_t seed, const Eigen::VectorXd &h, int n) {
            if (h.size() != stems.rows())
                throw std::invalid_argument("need one height per stem row");
            if (n < 3) throw std::invalid_argument("need n >= 3 points per section");
            const std::vector<sim::Stem> s = makeStems(stems, seed);
            RowMatrix out(static_cast<Eigen::Index>(s.size()) * n, 2);
            for (size_t i = 0; i < s.size(); ++i)
                out.middleRows(static_cast<Eigen::Index>(i) * n, n) =
                    sim::stemSection(s[i], h[i], n);
            return out;
        },
        py::arg("stems"), py::arg("seed"), py::arg("h"), py::arg("n") = 720,
        "Horizontal sections of the stem rows (as SimScene takes them, same seed) h (K,) metres "
        "above each row's base: (K*n, 2) world XY, n points per row at equal normalised "
        "azimuths.");
}

}  // namespace

void define_sim(py::module_ &m) {
    defineScanModel(m);
    defineSimResults(m);
    defineSimScene(m);
    defineStemSections(m);
    m.attr("SIM_SURFACES") =
        py::make_tuple("none", "ground", "stem", "branch", "foliage", "shrub", "log");
}

}  // namespace forestslam::python
