// Bindings of the forest ray caster (cpp/forestslam/sim): array conversion only.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

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

sim::ForestScene makeScene(double x0, double y0, double cell, const Eigen::MatrixXd &z,
                           const RowMatrix &stems, const RowMatrix &cylinders,
                           const RowMatrix &foliage, uint64_t seed, double grid_cell_m) {
    requireCols(stems, 12, "stems");
    requireCols(cylinders, 8, "cylinders");
    requireCols(foliage, 8, "foliage");
    sim::Heightfield terrain;
    if (z.size() > 0) terrain = sim::Heightfield(x0, y0, cell, z);
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
        for (int k = 0; k < 4; ++k)
            st.phase[k] =
                2.0 * M_PI * sim::hashUniform(sim::mixKey(seed, i), static_cast<uint64_t>(k));
    }
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

}  // namespace

void define_sim(py::module_ &m) {
    py::class_<sim::ForestScene>(m, "SimScene",
                                 "Forest scene for the LiDAR simulator: heightfield terrain plus "
                                 "stems, cylinders and foliage volumes in a uniform XY grid.")
        .def(py::init(&makeScene), py::arg("x0"), py::arg("y0"), py::arg("cell"), py::arg("z"),
             py::arg("stems"), py::arg("cylinders"), py::arg("foliage"), py::arg("seed") = 0,
             py::arg("grid_cell_m") = 3.0,
             "z (ny+1, nx+1) terrain vertex heights at x0 + ix*cell, y0 + iy*cell (empty: no "
             "ground). stems (K,12): x y z_base shear_x shear_y semi_a semi_b angle taper "
             "h_bottom height bark_amp (semi-axes at 1.3 m; radius scale 1 - taper (h - 1.3)). "
             "cylinders (M,8): x0 y0 z0 x1 y1 z1 radius surface. foliage (F,8): cx cy cz rx ry rz "
             "sigma surface. seed: bark phases.")
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
                return py::make_tuple(r.range, r.surface, r.object, r.cos_incidence);
            },
            py::arg("origins"), py::arg("dirs"), py::arg("range_min"), py::arg("range_max"),
            py::arg("seed") = 0,
            "origins (G,3) with G dividing N (ray i starts at origin i // (N/G)), unit dirs (N,3) "
            "-> (range (N,) NaN = no return, surface (N,) "
            "uint8 [0 none 1 ground 2 stem 3 branch 4 foliage 5 shrub 6 log], object (N,) int32 "
            "row in its table, cos_incidence (N,)).")
        .def(
            "synthesize",
            [](const sim::ForestScene &scene, const Eigen::Ref<const Eigen::VectorXd> &knot_time,
               const Eigen::Ref<const sim::PoseRows> &knot_pose,
               const Eigen::Ref<const Eigen::VectorXd> &group_time,
               const Eigen::Ref<const sim::IndexVector> &group,
               const Eigen::Ref<const Points3> &local_dirs, double range_min, double range_max,
               double range_noise, double dropout_rate, double intensity_scale,
               double intensity_noise_rel, uint64_t cast_seed, uint64_t noise_seed) {
                sim::ScanModel model;
                model.range_min_m = range_min;
                model.range_max_m = range_max;
                model.range_noise_m = range_noise;
                model.dropout_rate = dropout_rate;
                model.intensity_scale = intensity_scale;
                model.intensity_noise_rel = intensity_noise_rel;
                sim::SynthesizedScan r;
                {
                    py::gil_scoped_release release;
                    r = sim::synthesizeScan(scene, knot_time, knot_pose, group_time, group,
                                            local_dirs, model, cast_seed, noise_seed);
                }
                return py::make_tuple(r.ray, r.points, r.intensity, r.surface, r.object);
            },
            py::arg("knot_time"), py::arg("knot_pose"), py::arg("group_time"), py::arg("group"),
            py::arg("local_dirs"), py::arg("range_min"), py::arg("range_max"),
            py::arg("range_noise"), py::arg("dropout_rate"), py::arg("intensity_scale"),
            py::arg("intensity_noise_rel"), py::arg("cast_seed"), py::arg("noise_seed"),
            "One scan: knot_time (M,) increasing with knot_pose (M,16) row-major T_world_sensor, "
            "interpolated to group_time (G,); ray i fires local_dirs[i] (N,3, sensor frame) from "
            "the pose of group[i] (N,) int64. -> (ray (K,) int64 rows kept, points (K,3) sensor "
            "frame, intensity (K,) float32, surface (K,) uint8, object (K,) int32). Dropouts, "
            "range noise and intensity noise are drawn from noise_seed, foliage from cast_seed.")
        .def(
            "height_at",
            [](const sim::ForestScene &scene, const Eigen::Ref<const Points2> &xy) {
                Eigen::VectorXd z(xy.rows());
                for (Eigen::Index i = 0; i < xy.rows(); ++i)
                    z[i] = scene.terrain().heightAt(xy(i, 0), xy(i, 1));
                return z;
            },
            py::arg("xy"), "Terrain height at xy (N,2) -> (N,), NaN outside the heightfield.");
    m.attr("SIM_SURFACES") =
        py::make_tuple("none", "ground", "stem", "branch", "foliage", "shrub", "log");
}

}  // namespace forestslam::python
