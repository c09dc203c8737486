#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "bindings.hpp"
#include "forestslam/registration/ndt.hpp"
#include "forestslam/registration/stem_centre_lm.hpp"

namespace py = pybind11;

namespace forestslam::python {

namespace {

template <typename Config, typename T>
bool setField(Config &cfg, const std::string &key, const py::handle &value, const char *name,
              T Config::*member) {
    if (key != name) return false;
    cfg.*member = value.cast<T>();
    return true;
}

}  // namespace

void define_tls(py::module_ &m) {
    py::class_<registration::StemCentreTarget>(
        m, "StemCentreTarget",
        "KD-tree and height cells over a target cloud (M,3) for "
        "register_stem_centre_lm; build once, reuse for many frames.")
        .def(py::init([](const Eigen::Ref<const Points3> &points) {
                 py::gil_scoped_release release;
                 return std::make_unique<registration::StemCentreTarget>(points);
             }),
             py::arg("points"))
        .def("__len__", [](const registration::StemCentreTarget &t) { return t.size(); });

    m.def(
        "register_stem_centre_lm",
        [](const registration::StemCentreTarget &target, const Eigen::Ref<const Points3> &centres,
           const Eigen::Ref<const Eigen::VectorXd> &radii, const Eigen::Ref<const Points3> &real,
           const Pose3 &T_initial, const py::kwargs &kwargs) {
            registration::StemCentreLmConfig cfg;
            using C = registration::StemCentreLmConfig;
            registration::SweepTimes times;  // checked by registerStemCentreLm when sweep_order > 0
            for (const auto &item : kwargs) {
                const auto key = item.first.cast<std::string>();
                const auto &v = item.second;
                if (key == "centre_times") {
                    times.centres = v.cast<Eigen::VectorXd>();
                    continue;
                }
                if (key == "real_times") {
                    times.real = v.cast<Eigen::VectorXd>();
                    continue;
                }
                const bool ok =
                    setField(cfg, key, v, "max_rounds", &C::max_rounds) ||
                    setField(cfg, key, v, "max_solver_iterations", &C::max_solver_iterations) ||
                    setField(cfg, key, v, "virtual_gate_m", &C::virtual_gate_m) ||
                    setField(cfg, key, v, "virtual_sectors", &C::virtual_sectors) ||
                    setField(cfg, key, v, "virtual_window_m", &C::virtual_window_m) ||
                    setField(cfg, key, v, "virtual_max_gate_m", &C::virtual_max_gate_m) ||
                    setField(cfg, key, v, "real_gate_m", &C::real_gate_m) ||
                    setField(cfg, key, v, "plane_gate_m", &C::plane_gate_m) ||
                    setField(cfg, key, v, "min_triangle_ratio", &C::min_triangle_ratio) ||
                    setField(cfg, key, v, "robust_scale_m", &C::robust_scale_m) ||
                    setField(cfg, key, v, "coarse_gate_factor", &C::coarse_gate_factor) ||
                    setField(cfg, key, v, "gate_decay", &C::gate_decay) ||
                    setField(cfg, key, v, "virtual_weight", &C::virtual_weight) ||
                    setField(cfg, key, v, "min_inliers", &C::min_inliers) ||
                    setField(cfg, key, v, "converged_translation_m", &C::converged_translation_m) ||
                    setField(cfg, key, v, "converged_rotation_rad", &C::converged_rotation_rad) ||
                    setField(cfg, key, v, "degenerate_eigen_ratio", &C::degenerate_eigen_ratio) ||
                    setField(cfg, key, v, "sweep_order", &C::sweep_order) ||
                    setField(cfg, key, v, "sweep_prior_tau_s", &C::sweep_prior_tau_s) ||
                    setField(cfg, key, v, "sweep_prior_m", &C::sweep_prior_m) ||
                    setField(cfg, key, v, "sweep_prior_rad", &C::sweep_prior_rad);
                if (!ok) throw py::value_error("unknown option '" + key + "'");
            }
            if (centres.rows() != radii.size()) {
                throw py::value_error("centres and radii must have the same length");
            }
            registration::StemCentreLmResult r;
            {
                py::gil_scoped_release release;
                r = registration::registerStemCentreLm(target, centres, radii, real, T_initial, cfg,
                                                       &times);
            }
            py::dict out;
            out["T_target_source"] = r.T_target_source;
            out["covariance"] = r.covariance;
            out["converged"] = r.converged;
            out["degenerate"] = r.degenerate;
            out["inliers"] = r.inliers;
            out["virtual_inliers"] = r.virtual_inliers;
            out["real_inliers"] = r.real_inliers;
            out["virtual_rms_m"] = r.virtual_rms_m;
            out["real_rms_m"] = r.real_rms_m;
            out["rmse"] = r.rmse;
            out["iterations"] = r.iterations;
            out["sweep"] = r.sweep;
            return out;
        },
        py::arg("target"), py::arg("centres"), py::arg("radii"), py::arg("real_points"),
        py::arg("T_initial"),
        "Stem-centre LM: virtual features centres (V,3) + radii (V,), real features (R,3), all "
        "in the source frame, onto target from T_initial (4,4). -> dict T_target_source (4,4), "
        "covariance (6,6) over [tx,ty,tz,rx,ry,rz] (left perturbation), converged, degenerate, "
        "inliers, virtual_inliers, real_inliers, virtual_rms_m, real_rms_m, rmse, iterations, "
        "sweep (sweep_order,6) in-sweep motion coefficients. Options as keywords "
        "(StemCentreLmConfig field names); with sweep_order > 0 also centre_times (V,) and "
        "real_times (R,): feature times in seconds from the registration time.");

    m.def(
        "register_ndt",
        [](const Eigen::Ref<const Points3> &target, const Eigen::Ref<const Points3> &source,
           const Pose3 &T_initial, const py::kwargs &kwargs) {
            registration::NdtConfig cfg;
            using C = registration::NdtConfig;
            for (const auto &item : kwargs) {
                const auto key = item.first.cast<std::string>();
                const auto &v = item.second;
                const bool ok = setField(cfg, key, v, "voxel_m", &C::voxel_m) ||
                                setField(cfg, key, v, "resolution_m", &C::resolution_m) ||
                                setField(cfg, key, v, "step_size_m", &C::step_size_m) ||
                                setField(cfg, key, v, "epsilon", &C::epsilon) ||
                                setField(cfg, key, v, "max_iterations", &C::max_iterations) ||
                                setField(cfg, key, v, "max_range_m", &C::max_range_m) ||
                                setField(cfg, key, v, "min_points", &C::min_points);
                if (!ok) throw py::value_error("unknown option '" + key + "'");
            }
            registration::NdtResult r;
            {
                py::gil_scoped_release release;
                r = registration::registerNdt(target, source, T_initial, cfg);
            }
            py::dict out;
            out["T_target_source"] = r.T_target_source;
            out["converged"] = r.converged;
            out["iterations"] = r.iterations;
            out["fitness"] = r.fitness;
            return out;
        },
        py::arg("target"), py::arg("source"), py::arg("T_initial") = Pose3::Identity(),
        "3D-NDT (PCL) of source (N,3) onto target (M,3) from T_initial (4,4) -> dict "
        "T_target_source (4,4), converged, iterations, fitness (m^2). Options as keywords "
        "(NdtConfig field names).");
}

}  // namespace forestslam::python
