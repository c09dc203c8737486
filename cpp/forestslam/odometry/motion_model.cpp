#include "forestslam/odometry/motion_model.hpp"

#include <cmath>
#include <stdexcept>
#include <string>

#include "forestslam/registration/deskew.hpp"

namespace forestslam::odometry {

Vector6d poseToTwist(const Pose3 &T) {
    Vector6d xi;
    const Eigen::AngleAxisd aa(T.linear());
    xi << T.translation(), aa.angle() * aa.axis();
    return xi;
}

Pose3 twistToPose(const Vector6d &twist) { return registration::expSE3(twist); }

ConstantVelocityModel::ConstantVelocityModel(const MotionModelConfig &config) : config_(config) {
    if (!(config.max_gap_s > 0.0) || !(config.max_speed_mps > 0.0) ||
        !(config.max_turn_rate_dps > 0.0))
        throw std::invalid_argument(
            "motion model: max_gap_s, max_speed_mps and max_turn_rate_dps must be > 0");
}

StampCheck ConstantVelocityModel::beginScan(double t) {
    if (!std::isfinite(t)) throw std::invalid_argument("motion model: non-finite scan time");
    StampCheck check;
    if (!initialised_) return check;
    check.gap_s = t - t_;
    if (check.gap_s > config_.max_gap_s || check.gap_s <= 0.0) {
        check.restarted = true;
        restarted_ = true;
        twist_.setZero();
    } else if (t - twist_t_ > config_.max_gap_s) {
        // A velocity expires max_gap_s after it was measured, also when trusted poses without
        // a velocity of their own (each after a doubtful one) have kept the pose fresh.
        twist_.setZero();
    }
    return check;
}

Pose3 ConstantVelocityModel::predict(double t) const {
    if (!initialised_) return Pose3::Identity();
    return T_ * twistToPose(twist_ * (t - t_));
}

Points3 ConstantVelocityModel::deskew(const Eigen::Ref<const Points3> &points,
                                      const Eigen::Ref<const Eigen::VectorXd> &times) const {
    if (times.size() != points.rows())
        throw std::invalid_argument("deskew: " + std::to_string(times.size()) + " times for " +
                                    std::to_string(points.rows()) + " points");
    if (!initialised_ || twist_.isZero(0.0)) return points;
    return registration::deskewPoints(points, times, twist_);
}

void ConstantVelocityModel::update(double t, const Pose3 &T_world_sensor, bool trusted) {
    if (!trusted) {
        previous_trusted_ = false;
        return;
    }
    const double dt = t - t_;
    if (initialised_ && !restarted_ && previous_trusted_ && dt > 0.0) {
        twist_ = clamped(poseToTwist(T_.inverse() * T_world_sensor) / dt);
        twist_t_ = t;
    }
    T_ = T_world_sensor;
    t_ = t;
    initialised_ = true;
    restarted_ = false;
    previous_trusted_ = true;
}

void ConstantVelocityModel::reset() { *this = ConstantVelocityModel(config_); }

Vector6d ConstantVelocityModel::clamped(Vector6d twist) const {
    const double v = twist.head<3>().norm(), w = twist.tail<3>().norm();
    const double w_max = config_.max_turn_rate_dps * M_PI / 180.0;
    if (v > config_.max_speed_mps) twist.head<3>() *= config_.max_speed_mps / v;
    if (w > w_max) twist.tail<3>() *= w_max / w;
    return twist;
}

}  // namespace forestslam::odometry
