#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <limits>

#include "bindings.hpp"
#include "forestslam/common/circle_fit.hpp"

namespace py = pybind11;

namespace forestslam::python {
namespace {

py::dict circleDict(const CircleFit &f) {
    py::dict d;
    d["valid"] = f.valid;
    d["centre"] = f.centre;
    d["radius"] = f.radius;
    d["inliers"] = f.inliers;
    d["rms_m"] = f.rms_m;
    d["arc_coverage"] = f.arc_coverage;
    d["inlier_indices"] = f.inlier_indices;
    return d;
}

}  // namespace

void define_perception(py::module_ &m) {
    m.def(
        "fit_circle",
        [](const Eigen::Ref<const Points2> &xy, double inlier_threshold_m, double min_radius_m,
           double max_radius_m, int max_ransac_iterations, int arc_sectors, std::uint32_t seed) {
            CircleFitOptions o;
            o.inlier_threshold_m = inlier_threshold_m;
            o.min_radius_m = min_radius_m;
            o.max_radius_m = max_radius_m;
            o.max_ransac_iterations = max_ransac_iterations;
            o.arc_sectors = arc_sectors;
            o.seed = seed;
            CircleFit f;
            {
                py::gil_scoped_release release;
                f = fitCircle(xy, o);
            }
            return circleDict(f);
        },
        py::arg("xy"), py::arg("inlier_threshold_m") = 0.03, py::arg("min_radius_m") = 0.0,
        py::arg("max_radius_m") = std::numeric_limits<double>::infinity(),
        py::arg("max_ransac_iterations") = 200, py::arg("arc_sectors") = 36, py::arg("seed") = 42,
        "Robust circle fit (RANSAC + Taubin + Tukey-weighted geometric LM) of xy (N,2) float64.\n"
        "Returns dict: valid bool, centre (2,), radius, inliers int, rms_m, arc_coverage in [0,1]\n"
        "(occupied angular sectors), inlier_indices list[int] (rows of xy). Invalid (valid=False,\n"
        "NaN centre) for < 3 finite points, collinear points or a radius outside the bounds.");
    m.def(
        "fit_circle_algebraic",
        [](const Eigen::Ref<const Points2> &xy) { return circleDict(fitCircleAlgebraic(xy)); },
        py::arg("xy"), "Plain Taubin algebraic circle fit of xy (N,2); same dict as fit_circle.");
}

}  // namespace forestslam::python
