#pragma once

#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>

#include "forestslam/common/types.hpp"
#include "forestslam/perception/detector.hpp"

// Every C++ pose (forestslam::Pose3, an Eigen::Isometry3d) crosses the binding as a (4,4)
// float64 array; a matrix whose last row is not 0 0 0 1 is a ValueError, not a silent shear.
namespace pybind11::detail {
template <>
struct type_caster<forestslam::Pose3> {
    PYBIND11_TYPE_CASTER(forestslam::Pose3, const_name("numpy.ndarray[float64[4, 4]]"));

    bool load(handle src, bool convert) {
        type_caster<Eigen::Matrix4d> matrix;
        if (!matrix.load(src, convert)) return false;
        const Eigen::Matrix4d &T = matrix;
        const Eigen::RowVector4d last(0.0, 0.0, 0.0, 1.0);
        if (!((T.row(3) - last).cwiseAbs().maxCoeff() <= 1e-9))
            throw value_error("a pose is a (4,4) rigid transform whose last row is 0 0 0 1");
        value.matrix() = T;
        return true;
    }

    static handle cast(const forestslam::Pose3 &T, return_value_policy, handle parent) {
        return type_caster<Eigen::Matrix4d>::cast(Eigen::Matrix4d(T.matrix()),
                                                  return_value_policy::move, parent);
    }
};
}  // namespace pybind11::detail

// One field of a config struct as a typed read-write attribute of its bound class (the field's
// name is the attribute's): the one way config crosses into C++ (issue 18). Python fills these
// classes through forestslam.core_bridge, which names the key of an unknown field or a wrong type.
#define FS_FIELD(cls, T, name) cls.def_readwrite(#name, &T::name)

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
