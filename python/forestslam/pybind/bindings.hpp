#pragma once

#include <pybind11/pybind11.h>

#include "forestslam/perception/detector.hpp"

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

// The stems of a detection as the dict forestslam.perception.Stems is built from (perception.cpp),
// shared by the detector and the odometry bindings.
pybind11::dict detectionDict(const perception::Detection &det);

}  // namespace forestslam::python
