#include "bindings.hpp"

namespace py = pybind11;

namespace forestslam::python {

void define_tls(py::module_ &m) { (void)m; }

}  // namespace forestslam::python
