#pragma once

#include <pybind11/pybind11.h>

namespace forestslam::python {

void define_common(pybind11::module_ &m);
void define_io(pybind11::module_ &m);
void define_sim(pybind11::module_ &m);
void define_perception(pybind11::module_ &m);
void define_features(pybind11::module_ &m);
void define_registration(pybind11::module_ &m);
void define_localization(pybind11::module_ &m);
void define_odometry(pybind11::module_ &m);
void define_tls(pybind11::module_ &m);

}  // namespace forestslam::python
