#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>

#include "bindings.hpp"
#include "forestslam/common/types.hpp"

namespace py = pybind11;

namespace forestslam::python {

void define_common(py::module_ &m) {
    m.def("finite_rows", &finiteRows, py::arg("points"),
          "Rows of points (N,3) float64 whose coordinates are all finite -> (M,3).");
    m.def(
        "transform_points",
        [](const Pose3 &T, const Eigen::Ref<const Points3> &points) {
            return transformPoints(T, points);
        },
        py::arg("T"), py::arg("points"), "Apply a (4,4) pose to points (N,3) -> (N,3).");
}

}  // namespace forestslam::python
