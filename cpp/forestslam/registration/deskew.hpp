// Motion compensation of spinning-LiDAR scans with per-point time under constant velocity.
#pragma once

#include <Eigen/Core>

#include "forestslam/common/types.hpp"
#include "forestslam/registration/result.hpp"

namespace forestslam::registration {

// Points (N,3) measured at times (N,) seconds after the reference time, moved into the sensor
// frame at the reference time for a sensor moving with the body-frame twist (6,) per second
// (translation, rotation vector): p0 = R(t w) p + t v (Rodrigues). Rows with a non-finite
// time are returned unchanged. `times` must have N entries (std::invalid_argument otherwise).
Points3 deskewPoints(const Eigen::Ref<const Points3> &points,
                     const Eigen::Ref<const Eigen::VectorXd> &times, const Vector6d &twist_per_s);

}  // namespace forestslam::registration
