// Registration bindings: tree correspondences, shape-to-shape, point-to-plane ICP, FPFH baseline.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "bindings.hpp"
#include "forestslam/registration/deskew.hpp"
#include "forestslam/registration/fpfh_ransac.hpp"
#include "forestslam/registration/point_to_plane_icp.hpp"
#include "forestslam/registration/shape_registration.hpp"
#include "forestslam/registration/tree_correspondences.hpp"

namespace py = pybind11;

namespace forestslam::python {
namespace {

namespace rg = forestslam::registration;

using PairArray = Eigen::Matrix<int, Eigen::Dynamic, 2, Eigen::RowMajor>;

std::vector<std::pair<int, int>> toPairs(const PairArray &a) {
    std::vector<std::pair<int, int>> out(a.rows());
    for (Eigen::Index i = 0; i < a.rows(); ++i) out[i] = {a(i, 0), a(i, 1)};
    return out;
}

void defineDeskew(py::module_ &m) {
    m.def(
        "deskew_points",
        [](const Eigen::Ref<const Points3> &points, const Eigen::Ref<const Eigen::VectorXd> &times,
           const Vector6d &twist_per_s) {
            py::gil_scoped_release release;
            return registration::deskewPoints(points, times, twist_per_s);
        },
        py::arg("points"), py::arg("times"), py::arg("twist_per_s"),
        "Constant-velocity motion compensation: points (N,3) float64 measured at times (N,) s\n"
        "after the reference, moved into the sensor frame at the reference for the body twist\n"
        "(6,) per second (translation, rotation vector): p0 = R(t w) p + t v. Rows with a\n"
        "non-finite time are unchanged. Returns (N,3).");
}

// The result every registration returns, and the option structs as typed classes.
void defineRegistrationTypes(py::module_ &m) {
    // Read-only, like small_gicp's: a result is made by a registration, never filled in Python.
    using Result = registration::RegistrationResult;
    py::class_<Result>(m, "RegistrationResult",
                       "What every registration returns (read-only; made by the registration "
                       "functions).")
        .def_readonly("T_target_source", &Result::T_target_source,
                      "(4,4) float64: maps source-frame points into the target frame.")
        .def_readonly("covariance", &Result::covariance,
                      "(6,6) over the left perturbation (tx,ty,tz,rx,ry,rz); planar methods fill "
                      "x, y, yaw (0, 1, 5) and leave the others at a large variance.")
        .def_readonly("converged", &Result::converged)
        .def_readonly("degenerate", &Result::degenerate,
                      "True when the pose is not well constrained (too few inliers, a weak "
                      "direction, a failed RANSAC).")
        .def_readonly("inliers", &Result::inliers,
                      "Matched pairs / ICP correspondences used at the end.")
        .def_readonly("iterations", &Result::iterations)
        .def_readonly("rmse", &Result::rmse, "Residual RMS of the inliers at the end, m.")
        .def("__repr__", [](const Result &r) {
            return "RegistrationResult(converged=" + std::to_string(r.converged) +
                   ", degenerate=" + std::to_string(r.degenerate) +
                   ", inliers=" + std::to_string(r.inliers) + ", rmse=" + std::to_string(r.rmse) +
                   ")";
        });

    py::class_<rg::ShapeRegistrationConfig> s(m, "ShapeRegistrationConfig");
    s.def(py::init<>());
    FS_FIELD(s, rg::ShapeRegistrationConfig, min_sigma_m);
    FS_FIELD(s, rg::ShapeRegistrationConfig, consensus_tolerance_m);
    FS_FIELD(s, rg::ShapeRegistrationConfig, inlier_threshold_m);
    FS_FIELD(s, rg::ShapeRegistrationConfig, max_consensus_pairs);
    FS_FIELD(s, rg::ShapeRegistrationConfig, max_iterations);
    FS_FIELD(s, rg::ShapeRegistrationConfig, min_inliers_not_degenerate);

    py::class_<rg::IcpConfig> i(m, "IcpConfig");
    i.def(py::init<>());
    FS_FIELD(i, rg::IcpConfig, max_iterations);
    FS_FIELD(i, rg::IcpConfig, max_correspondence_m);
    FS_FIELD(i, rg::IcpConfig, final_correspondence_m);
    FS_FIELD(i, rg::IcpConfig, shrink_iterations);
    FS_FIELD(i, rg::IcpConfig, coarse_stride);
    FS_FIELD(i, rg::IcpConfig, huber_m);
    FS_FIELD(i, rg::IcpConfig, translation_tolerance_m);
    FS_FIELD(i, rg::IcpConfig, rotation_tolerance_rad);
    FS_FIELD(i, rg::IcpConfig, min_correspondences);
    FS_FIELD(i, rg::IcpConfig, degeneracy_threshold);
    FS_FIELD(i, rg::IcpConfig, degeneracy_length_m);
    FS_FIELD(i, rg::IcpConfig, normal_k);

    py::class_<rg::FpfhConfig> f(m, "FpfhConfig");
    f.def(py::init<>());
    FS_FIELD(f, rg::FpfhConfig, voxel_m);
    FS_FIELD(f, rg::FpfhConfig, normal_radius_m);
    FS_FIELD(f, rg::FpfhConfig, feature_radius_m);
    FS_FIELD(f, rg::FpfhConfig, ransac_iterations);
    FS_FIELD(f, rg::FpfhConfig, correspondence_randomness);
    FS_FIELD(f, rg::FpfhConfig, similarity_threshold);
    FS_FIELD(f, rg::FpfhConfig, inlier_distance_m);
    FS_FIELD(f, rg::FpfhConfig, inlier_fraction);
    FS_FIELD(f, rg::FpfhConfig, seed);
    FS_FIELD(f, rg::FpfhConfig, icp);
}

// consensus_pairs' result: the pose and the pairs that agree with it.
struct ConsensusPairs {
    Pose3 T_target_source;
    std::vector<int> inliers;
};

// Tree correspondences and the shape-to-shape registration over x, y, yaw.
void defineTreeRegistration(py::module_ &m) {
    m.def(
        "match_trees",
        [](const Eigen::Ref<const Points3> &source, const Eigen::Ref<const Points3> &target,
           const Pose3 &T_pred, double gate_m, double ratio) {
            const auto pairs = registration::matchTrees(source, target, T_pred, gate_m, ratio);
            PairArray out(pairs.size(), 2);
            for (size_t i = 0; i < pairs.size(); ++i) out.row(i) << pairs[i].first, pairs[i].second;
            return out;
        },
        py::arg("source"), py::arg("target"), py::arg("T_target_source_predicted"),
        py::arg("gate_m"), py::arg("ratio") = 1.0,
        "Mutually exclusive nearest stems in XY: source (K,3), target (M,3) -> pairs (P,2) int "
        "(source index, target index) within gate_m after applying the predicted (4,4) pose.");

    m.def(
        "register_shapes",
        [](const Eigen::Ref<const Points3> &source_means,
           const registration::Covariances &source_covs,
           const Eigen::Ref<const Points3> &target_means,
           const registration::Covariances &target_covs, const PairArray &pairs,
           const Pose3 &T_init, const registration::ShapeRegistrationConfig &config) {
            return registration::registerShapes(source_means, source_covs, target_means,
                                                target_covs, toPairs(pairs), T_init, config);
        },
        py::arg("source_means"), py::arg("source_covs"), py::arg("target_means"),
        py::arg("target_covs"), py::arg("pairs"), py::arg("T_init"),
        py::arg("config") = registration::ShapeRegistrationConfig(),
        "Shape-to-shape Gaussian registration over x, y, yaw (Eq. 3): means (K,3), covs (K,9) "
        "row-major 3x3, pairs (P,2) -> RegistrationResult.");

    py::class_<ConsensusPairs>(m, "ConsensusPairs", "consensus_pairs' result (read-only).")
        .def_readonly("T_target_source", &ConsensusPairs::T_target_source,
                      "(4,4) planar pose with most pairs within inlier_threshold_m")
        .def_property_readonly(
            "inliers",
            [](const ConsensusPairs &c) {
                return Eigen::Map<const Eigen::VectorXi>(
                           c.inliers.data(), static_cast<Eigen::Index>(c.inliers.size()))
                    .eval();
            },
            "(I,) int indices into pairs of the inlier pairs");
    m.def(
        "consensus_pairs",
        [](const Eigen::Ref<const Points3> &source, const Eigen::Ref<const Points3> &target,
           const PairArray &pairs, const Pose3 &T_init,
           const registration::ShapeRegistrationConfig &config) {
            auto [T, inliers] =
                registration::consensusPairs(source, target, toPairs(pairs), T_init, config);
            return ConsensusPairs{T, std::move(inliers)};
        },
        py::arg("source"), py::arg("target"), py::arg("pairs"), py::arg("T_init"),
        py::arg("config") = registration::ShapeRegistrationConfig(),
        "Consensus over pairs of stem matches (P,2) -> ConsensusPairs (planar pose, inlier pair "
        "indices).");
}

// Point-to-plane ICP and the FPFH baseline.
void defineIcp(py::module_ &m) {
    py::class_<registration::PlaneTarget>(
        m, "PlaneTarget",
        "ICP target: points (M,3) with a KD-tree and PCA normals (M,3; NaN rows "
        "where the neighbourhood is not planar).")
        .def(py::init([](const Eigen::Ref<const Points3> &points, int normal_k) {
                 py::gil_scoped_release release;
                 return std::make_unique<registration::PlaneTarget>(points, normal_k);
             }),
             py::arg("points"), py::arg("normal_k") = 10)
        .def_property_readonly("points", &registration::PlaneTarget::points)
        .def_property_readonly("normals", &registration::PlaneTarget::normals)
        .def("__len__", [](const registration::PlaneTarget &t) { return t.size(); });

    m.def(
        "icp_point_to_plane",
        [](const registration::PlaneTarget &target, const Eigen::Ref<const Points3> &source,
           const Pose3 &T_init, const registration::IcpConfig &config,
           const Matrix6d &prior_information, const Pose3 &T_prior) {
            py::gil_scoped_release release;
            return registration::icpPointToPlane(target, source, T_init, config, prior_information,
                                                 T_prior);
        },
        py::arg("target"), py::arg("source"), py::arg("T_init"),
        py::arg("config") = registration::IcpConfig(),
        py::arg("prior_information") = Matrix6d::Zero(), py::arg("T_prior") = Pose3::Identity(),
        "Point-to-plane ICP, 6 DoF: source (N,3) onto a PlaneTarget from T_init (4,4); optional "
        "prior information (6,6) towards T_prior (4,4) -> RegistrationResult.");

    m.def(
        "register_fpfh",
        [](const Eigen::Ref<const Points3> &source, const Eigen::Ref<const Points3> &target,
           const Pose3 &T_init, const registration::FpfhConfig &config) {
            py::gil_scoped_release release;
            return registration::registerFpfh(source, target, T_init, config);
        },
        py::arg("source"), py::arg("target"), py::arg("T_init") = Pose3::Identity(),
        py::arg("config") = registration::FpfhConfig(),
        "FPFH + RANSAC (SampleConsensusPrerejective) + point-to-plane ICP baseline: source (N,3), "
        "target (M,3) -> RegistrationResult (inliers = RANSAC inliers).");

    m.def("voxel_centroids", &registration::voxelCentroids, py::arg("points"), py::arg("voxel_m"),
          "Voxel-grid centroids of points (N,3) -> (M,3).");
}

}  // namespace

void define_registration(py::module_ &m) {
    defineDeskew(m);
    defineRegistrationTypes(m);
    defineTreeRegistration(m);
    defineIcp(m);
}

}  // namespace forestslam::python
