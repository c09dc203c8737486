#include "forestslam/registration/result.hpp"

#include <cmath>

namespace forestslam::registration {

Pose3 planarToPose(double x, double y, double yaw) {
    Pose3 T = Pose3::Identity();
    T.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T.translation() << x, y, 0.0;
    return T;
}

Eigen::Vector3d poseToPlanar(const Pose3 &T) {
    const Eigen::Matrix3d R = T.linear();
    return {T.translation().x(), T.translation().y(), std::atan2(R(1, 0), R(0, 0))};
}

Pose3 expSE3(const Vector6d &delta) {
    Pose3 T = Pose3::Identity();
    const Eigen::Vector3d w = delta.tail<3>();
    const double angle = w.norm();
    if (angle > 1e-12) T.linear() = Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
    T.translation() = delta.head<3>();
    return T;
}

}  // namespace forestslam::registration
