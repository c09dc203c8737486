// TLS registration bindings: the stem-centre LM (Shao et al.) and 3D-NDT, their option structs
// as typed classes (config crosses into C++ one way).
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <optional>
#include <string>

#include "bindings.hpp"
#include "forestslam/registration/ndt.hpp"
#include "forestslam/registration/stem_centre_lm.hpp"

namespace py = pybind11;

namespace forestslam::python {
namespace {

namespace rg = forestslam::registration;

void defineTlsConfigs(py::module_ &m) {
    py::class_<rg::StemCentreLmConfig> c(m, "StemCentreLmConfig");
    c.def(py::init<>());
    FS_FIELD(c, rg::StemCentreLmConfig, max_rounds);
    FS_FIELD(c, rg::StemCentreLmConfig, max_solver_iterations);
    FS_FIELD(c, rg::StemCentreLmConfig, virtual_gate_m);
    FS_FIELD(c, rg::StemCentreLmConfig, virtual_sectors);
    FS_FIELD(c, rg::StemCentreLmConfig, virtual_window_m);
    FS_FIELD(c, rg::StemCentreLmConfig, virtual_max_gate_m);
    FS_FIELD(c, rg::StemCentreLmConfig, real_gate_m);
    FS_FIELD(c, rg::StemCentreLmConfig, plane_gate_m);
    FS_FIELD(c, rg::StemCentreLmConfig, min_triangle_ratio);
    FS_FIELD(c, rg::StemCentreLmConfig, robust_scale_m);
    FS_FIELD(c, rg::StemCentreLmConfig, coarse_gate_factor);
    FS_FIELD(c, rg::StemCentreLmConfig, gate_decay);
    FS_FIELD(c, rg::StemCentreLmConfig, virtual_weight);
    FS_FIELD(c, rg::StemCentreLmConfig, converged_translation_m);
    FS_FIELD(c, rg::StemCentreLmConfig, converged_rotation_rad);
    FS_FIELD(c, rg::StemCentreLmConfig, min_inliers);
    FS_FIELD(c, rg::StemCentreLmConfig, degenerate_eigen_ratio);
    FS_FIELD(c, rg::StemCentreLmConfig, sweep_order);
    FS_FIELD(c, rg::StemCentreLmConfig, sweep_prior_tau_s);
    FS_FIELD(c, rg::StemCentreLmConfig, sweep_prior_m);
    FS_FIELD(c, rg::StemCentreLmConfig, sweep_prior_rad);

    py::class_<rg::NdtConfig> n(m, "NdtConfig");
    n.def(py::init<>());
    FS_FIELD(n, rg::NdtConfig, voxel_m);
    FS_FIELD(n, rg::NdtConfig, resolution_m);
    FS_FIELD(n, rg::NdtConfig, step_size_m);
    FS_FIELD(n, rg::NdtConfig, epsilon);
    FS_FIELD(n, rg::NdtConfig, max_iterations);
    FS_FIELD(n, rg::NdtConfig, max_range_m);
    FS_FIELD(n, rg::NdtConfig, min_points);
}

// The results, read-only like RegistrationResult (made by the registration functions).
void defineTlsResults(py::module_ &m) {
    using Lm = rg::StemCentreLmResult;
    py::class_<Lm, rg::RegistrationResult>(
        m, "StemCentreLmResult",
        "register_stem_centre_lm's result (read-only): RegistrationResult (T_target_source, "
        "covariance (6,6) over [tx,ty,tz,rx,ry,rz] (left perturbation), converged, degenerate, "
        "inliers, iterations, rmse) plus the pairs of each kind.")
        .def_readonly("virtual_inliers", &Lm::virtual_inliers, "stem-centre (virtual) pairs")
        .def_readonly("real_inliers", &Lm::real_inliers, "point-to-plane (real) pairs")
        .def_readonly("virtual_rms_m", &Lm::virtual_rms_m,
                      "RMS of distance - radius over the virtual pairs (0 without any)")
        .def_readonly("real_rms_m", &Lm::real_rms_m,
                      "RMS point-to-plane distance over the real pairs (0 without any)")
        .def_readonly("sweep", &Lm::sweep,
                      "(sweep_order, 6) in-sweep motion: row k-1 the coefficient of tau^k of "
                      "[t, w] in the target frame; (0, 6) when rigid")
        .def("__repr__", [](const Lm &r) {
            return "StemCentreLmResult(converged=" + std::to_string(r.converged) +
                   ", degenerate=" + std::to_string(r.degenerate) +
                   ", virtual_inliers=" + std::to_string(r.virtual_inliers) +
                   ", virtual_rms_m=" + std::to_string(r.virtual_rms_m) + ")";
        });

    py::class_<rg::NdtResult>(m, "NdtResult", "register_ndt's result (read-only).")
        .def_readonly("T_target_source", &rg::NdtResult::T_target_source,
                      "(4,4); the initial guess when not converged")
        .def_readonly("converged", &rg::NdtResult::converged)
        .def_readonly("iterations", &rg::NdtResult::iterations)
        .def_readonly("fitness", &rg::NdtResult::fitness,
                      "PCL fitness score: mean squared nearest distance (m^2)")
        .def("__repr__", [](const rg::NdtResult &r) {
            return "NdtResult(converged=" + std::to_string(r.converged) +
                   ", fitness=" + std::to_string(r.fitness) + ")";
        });
}

void defineStemCentreLm(py::module_ &m) {
    py::class_<rg::StemCentreTarget>(m, "StemCentreTarget",
                                     "KD-tree and height cells over a target cloud (M,3) for "
                                     "register_stem_centre_lm; build once, reuse for many frames.")
        .def(py::init([](const Eigen::Ref<const Points3> &points) {
                 py::gil_scoped_release release;
                 return std::make_unique<rg::StemCentreTarget>(points);
             }),
             py::arg("points"))
        .def("__len__", [](const rg::StemCentreTarget &t) { return t.size(); });

    py::class_<rg::StemCentreLmCache>(
        m, "StemCentreLmCache",
        "Pair candidates kept between register_stem_centre_lm calls with the same features on "
        "the same target (e.g. one frame's rigid and in-sweep LM): same results, fewer "
        "searches. One per frame; not shared between threads.")
        .def(py::init<>());

    m.def(
        "register_stem_centre_lm",
        [](const rg::StemCentreTarget &target, const Eigen::Ref<const Points3> &centres,
           const Eigen::Ref<const Eigen::VectorXd> &radii, const Eigen::Ref<const Points3> &real,
           const Pose3 &T_initial, const rg::StemCentreLmConfig &config,
           std::optional<Eigen::VectorXd> centre_times, std::optional<Eigen::VectorXd> real_times,
           rg::StemCentreLmCache *cache) {
            if (centres.rows() != radii.size()) {
                throw py::value_error("centres and radii must have the same length");
            }
            const rg::StemCentreLmConfig cfg = config;  // a copy: used without the GIL
            rg::SweepTimes times;  // checked by registerStemCentreLm when sweep_order > 0
            if (centre_times) times.centres = std::move(*centre_times);
            if (real_times) times.real = std::move(*real_times);
            rg::StemCentreLmResult r;
            {
                py::gil_scoped_release release;
                r = rg::registerStemCentreLm(target, centres, radii, real, T_initial, cfg, &times,
                                             cache);
            }
            return r;
        },
        py::arg("target"), py::arg("centres"), py::arg("radii"), py::arg("real_points"),
        py::arg("T_initial"), py::arg("config") = rg::StemCentreLmConfig(),
        py::arg("centre_times") = py::none(), py::arg("real_times") = py::none(),
        py::arg("cache") = nullptr,
        "Stem-centre LM: virtual features centres (V,3) + radii (V,), real features (R,3), all "
        "in the source frame, onto target from T_initial (4,4); config: StemCentreLmConfig. "
        "-> StemCentreLmResult. With config.sweep_order > 0 also centre_times (V,) and "
        "real_times (R,): "
        "feature times in seconds from the registration time. cache: a StemCentreLmCache "
        "(optional) whose candidates the call reuses and leaves for the next.");
}

void defineNdt(py::module_ &m) {
    m.def(
        "register_ndt",
        [](const Eigen::Ref<const Points3> &target, const Eigen::Ref<const Points3> &source,
           const Pose3 &T_initial, const rg::NdtConfig &config) {
            const rg::NdtConfig cfg = config;
            rg::NdtResult r;
            {
                py::gil_scoped_release release;
                r = rg::registerNdt(target, source, T_initial, cfg);
            }
            return r;
        },
        py::arg("target"), py::arg("source"), py::arg("T_initial") = Pose3::Identity(),
        py::arg("config") = rg::NdtConfig(),
        "3D-NDT (PCL) of source (N,3) onto target (M,3) from T_initial (4,4); config: NdtConfig. "
        "-> NdtResult.");
}

}  // namespace

void define_tls(py::module_ &m) {
    defineTlsConfigs(m);
    defineTlsResults(m);
    defineStemCentreLm(m);
    defineNdt(m);
}

}  // namespace forestslam::python
