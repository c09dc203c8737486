// Odometry bindings: the tree odometry, its motion model and every option struct it takes
// (perception's are bound in perception.cpp), each as a typed class: config crosses into C++
// one way.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <optional>

#include "bindings.hpp"
#include "forestslam/odometry/motion_model.hpp"
#include "forestslam/odometry/tree_odometry.hpp"

namespace py = pybind11;

namespace forestslam::python {
namespace {

namespace pc = forestslam::perception;
namespace od = forestslam::odometry;

void defineOdometryConfig(py::module_ &m) {
    py::class_<od::MotionModelConfig> mm(m, "MotionModelConfig");
    mm.def(py::init<>());
    FS_FIELD(mm, od::MotionModelConfig, max_gap_s);
    FS_FIELD(mm, od::MotionModelConfig, max_speed_mps);
    FS_FIELD(mm, od::MotionModelConfig, max_turn_rate_dps);

    py::class_<od::TreeMatchConfig> t(m, "TreeMatchConfig");
    t.def(py::init<>());
    FS_FIELD(t, od::TreeMatchConfig, gate_m);
    FS_FIELD(t, od::TreeMatchConfig, ratio);

    py::class_<od::RegistrationConfig> r(m, "RegistrationConfig");
    r.def(py::init<>());
    FS_FIELD(r, od::RegistrationConfig, trees);
    FS_FIELD(r, od::RegistrationConfig, shape);
    FS_FIELD(r, od::RegistrationConfig, icp);
    FS_FIELD(r, od::RegistrationConfig, fpfh);

    py::class_<od::OdometryConfig> c(m, "OdometryConfig");
    c.def(py::init<>());
    FS_FIELD(c, od::OdometryConfig, method);
    FS_FIELD(c, od::OdometryConfig, mode);
    FS_FIELD(c, od::OdometryConfig, deskew);
    FS_FIELD(c, od::OdometryConfig, min_stems);
    FS_FIELD(c, od::OdometryConfig, source_voxel_m);
    FS_FIELD(c, od::OdometryConfig, max_source_points);
    FS_FIELD(c, od::OdometryConfig, keyframe_distance_m);
    FS_FIELD(c, od::OdometryConfig, keyframe_yaw_deg);
    FS_FIELD(c, od::OdometryConfig, local_map_keyframes);
    FS_FIELD(c, od::OdometryConfig, local_map_radius_m);
    FS_FIELD(c, od::OdometryConfig, map_voxel_m);
    FS_FIELD(c, od::OdometryConfig, stem_merge_m);
    FS_FIELD(c, od::OdometryConfig, prior_sigma_m);
    FS_FIELD(c, od::OdometryConfig, prior_sigma_deg);
    FS_FIELD(c, od::OdometryConfig, max_correction_m);
    FS_FIELD(c, od::OdometryConfig, max_correction_deg);
    FS_FIELD(c, od::OdometryConfig, max_speed_mps);
    FS_FIELD(c, od::OdometryConfig, max_turn_rate_dps);
    FS_FIELD(c, od::OdometryConfig, max_stamp_gap_s);
    FS_FIELD(c, od::OdometryConfig, fpfh_max_points);
    FS_FIELD(c, od::OdometryConfig, registration);
    m.def("validate_odometry_config", &od::validate, py::arg("config"),
          "ValueError naming the field when a value is out of range or unknown.");

    py::class_<od::OdometrySensor> s(m, "OdometrySensor",
                                     "kind (spinning, solid_state, tls, map), geometry "
                                     "(SensorGeometry), intensity_threshold (NaN: none).");
    s.def(py::init<>());
    FS_FIELD(s, od::OdometrySensor, geometry);
    FS_FIELD(s, od::OdometrySensor, kind);
    FS_FIELD(s, od::OdometrySensor, intensity_threshold);
}

void defineMotionModel(py::module_ &m) {
    m.def(
        "twist_to_pose", [](const Vector6d &xi) { return od::twistToPose(xi).matrix(); },
        py::arg("twist"),
        "(4,4) pose of a twist (6,) = (translation, rotation vector); the translation as is.");
    m.def(
        "pose_to_twist", [](const Pose3 &T) { return od::poseToTwist(T); }, py::arg("T"),
        "Twist (6,) = (translation, rotation vector) of a (4,4) pose; inverse of twist_to_pose.");
    py::class_<od::StampCheck>(m, "StampCheck",
                               "restarted: the velocity was forgotten (gap "
                               "above max_gap_s or time not advancing); gap_s.")
        .def_readonly("restarted", &od::StampCheck::restarted)
        .def_readonly("gap_s", &od::StampCheck::gap_s);
    py::class_<od::ConstantVelocityModel>(
        m, "ConstantVelocityModel",
        "Constant-velocity motion model: begin_scan(t) once per scan (restarts on a long gap or a "
        "jump back), predict(t) -> T_world_sensor (4,4), deskew(points (N,3), times (N,) s "
        "relative to t), update(t, T_world_sensor, trusted=True) after registration.")
        .def(py::init<const od::MotionModelConfig &>(), py::arg("config") = od::MotionModelConfig())
        .def("begin_scan", &od::ConstantVelocityModel::beginScan, py::arg("t"))
        .def(
            "predict",
            [](const od::ConstantVelocityModel &mm, double t) { return mm.predict(t).matrix(); },
            py::arg("t"))
        .def("deskew", &od::ConstantVelocityModel::deskew, py::arg("points"), py::arg("times"))
        .def(
            "update",
            [](od::ConstantVelocityModel &mm, double t, const Pose3 &T, bool trusted) {
                mm.update(t, T, trusted);
            },
            py::arg("t"), py::arg("T_world_sensor"), py::arg("trusted") = true,
            "An untrusted pose is not kept (predictions from the last trusted one) and the next "
            "trusted pose does not estimate the velocity across it.")
        .def("reset", &od::ConstantVelocityModel::reset)
        .def_property_readonly("initialised", &od::ConstantVelocityModel::initialised)
        .def_property_readonly("twist", &od::ConstantVelocityModel::twist,
                               "body-frame velocity (6,) per second (translation, rotation)")
        .def_property_readonly(
            "pose", [](const od::ConstantVelocityModel &mm) { return mm.pose().matrix(); })
        .def_property_readonly("time", &od::ConstantVelocityModel::time);
}

void defineTreeOdometry(py::module_ &m) {
    py::class_<od::OdometryResult>(
        m, "OdometryResult",
        "One scan's odometry: stamp, T_world_sensor (4,4) at the stamp, covariance (3,3) x y yaw "
        "and covariance6 (6,6) (None without a registration), body frame; degraded, method, "
        "matched_stems, stems (Detection), stamp_check, "
        "perception_error, timing (wall ms) and cpu_ms (process CPU ms) per stage.")
        .def_readonly("stamp", &od::OdometryResult::stamp)
        .def_readonly("T_world_sensor", &od::OdometryResult::T_world_sensor)
        .def_readonly("covariance", &od::OdometryResult::covariance)
        .def_property_readonly("covariance6",
                               [](const od::OdometryResult &r) -> std::optional<Matrix6d> {
                                   if (!r.has_covariance6) return std::nullopt;
                                   return r.covariance6;
                               })
        .def_readonly("degraded", &od::OdometryResult::degraded)
        .def_readonly("method", &od::OdometryResult::method)
        .def_readonly("matched_stems", &od::OdometryResult::matched_stems)
        .def_readonly("stems", &od::OdometryResult::detection,
                      "the scan's stems: Detection (read-only, sensor frame)")
        .def_readonly("stamp_check", &od::OdometryResult::stamp_check)
        .def_readonly("perception_error", &od::OdometryResult::perception_error)
        .def_readonly("timing", &od::OdometryResult::timing_ms)
        .def_readonly("cpu_ms", &od::OdometryResult::cpu_ms);

    py::class_<od::TreeOdometry>(m, "TreeOdometry",
                                 "Per-scan tree odometry (deskew, perception, tree matching, "
                                 "shape-to-shape, ICP, local map) with its motion model.")
        .def(py::init<const od::OdometrySensor &, const od::OdometryConfig &,
                      const pc::PerceptionConfig &>(),
             py::arg("sensor"), py::arg("config") = od::OdometryConfig(),
             py::arg("perception") = pc::PerceptionConfig())
        .def(
            "register_scan",
            [](od::TreeOdometry &odo, double stamp, const Eigen::Ref<const Points3> &points,
               std::optional<Eigen::VectorXd> intensity, std::optional<Eigen::VectorXi> ring,
               std::optional<Eigen::VectorXd> time) {
                od::LidarScan scan;
                scan.stamp = stamp;
                scan.points = points;
                if (intensity) scan.intensity = std::move(*intensity);
                if (ring) scan.ring = std::move(*ring);
                if (time) scan.time = std::move(*time);
                py::gil_scoped_release release;
                return odo.registerScan(scan);
            },
            py::arg("stamp"), py::arg("points"), py::arg("intensity") = py::none(),
            py::arg("ring") = py::none(), py::arg("time") = py::none(),
            "Register one scan: points (N,3) float64, intensity (N,), ring (N,) int, time (N,) s "
            "after the stamp, each optional -> OdometryResult.")
        .def_property_readonly("scans", &od::TreeOdometry::scans)
        .def_property_readonly("motion_model", &od::TreeOdometry::motionModel,
                               py::return_value_policy::reference_internal)
        .def_property_readonly("local_map_keyframes",
                               [](const od::TreeOdometry &o) { return o.localMap().keyframes(); });
}

}  // namespace

void define_odometry(py::module_ &m) {
    defineOdometryConfig(m);
    defineMotionModel(m);
    defineTreeOdometry(m);
}

}  // namespace forestslam::python
