// forestslam._core: the thin Python layer over the C++ core. One topic per file, define_<topic>(m).
#include <pybind11/pybind11.h>

#include "bindings.hpp"

PYBIND11_MODULE(_core, m) {
    m.doc() = "forestslam C++ core (points (N,3) float64 C-contiguous, poses (4,4) float64)";
    forestslam::python::define_common(m);
    forestslam::python::define_io(m);
    forestslam::python::define_sim(m);
    forestslam::python::define_perception(m);
    forestslam::python::define_features(m);
    forestslam::python::define_registration(m);
    forestslam::python::define_localization(m);
    forestslam::python::define_odometry(m);
    forestslam::python::define_tls(m);
}
