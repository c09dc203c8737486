// Constant-velocity motion model of a moving LiDAR: the prediction of the next pose, the
// deskew of a sweep with per-point time, and the velocity update from two registered poses.
// A gap between scans above max_gap_s (a dropped recording, a paused bag) or a time that does
// not advance restarts the model: the velocity is forgotten, so that no prediction is ever
// multiplied by the gap (a 120 s gap at 1 m/s would otherwise throw the next pose 120 m away).
#pragma once

#include "forestslam/common/types.hpp"
#include "forestslam/registration/result.hpp"

namespace forestslam::odometry {

struct MotionModelConfig {
    double max_gap_s = 1.0;           // longer gaps between scans restart the model
    double max_speed_mps = 5.0;       // the velocity is clamped to what a platform can do, so
    double max_turn_rate_dps = 90.0;  // that one wrong registration cannot run away with it
};

// What beginScan found about the time since the previous scan.
struct StampCheck {
    bool restarted = false;  // the velocity was forgotten: gap too long or time not advancing
    double gap_s = 0.0;      // time since the previous scan (negative: a jump back)
};

// Body-frame twist (translation (3), rotation vector (3)) of a pose and back. The translation is
// taken as is (not the SE(3) V^-1 t): exact enough for the small per-scan motions it serves.
Vector6d poseToTwist(const Pose3 &T);
Pose3 twistToPose(const Vector6d &twist);

class ConstantVelocityModel {
  public:
    explicit ConstantVelocityModel(const MotionModelConfig &config = {});

    // Once per scan, with its reference time (s), before predict / deskew.
    StampCheck beginScan(double t);
    // T_world_sensor at time t: the last pose moved on by the velocity (identity before any).
    Pose3 predict(double t) const;
    // Points (N,3) measured at times (N,) s relative to the reference time, moved into the
    // sensor frame at the reference time (unchanged while the velocity is unknown).
    Points3 deskew(const Eigen::Ref<const Points3> &points,
                   const Eigen::Ref<const Eigen::VectorXd> &times) const;
    // The registered pose at time t; the velocity from the previous pose unless just restarted.
    // An untrusted pose (a registration the caller doubts) is not kept: predictions go on from
    // the last trusted one, and the next trusted pose keeps the velocity rather than estimating
    // it across the doubtful one.
    void update(double t, const Pose3 &T_world_sensor, bool trusted = true);
    void reset();

    bool initialised() const { return initialised_; }
    const Vector6d &twist() const { return twist_; }  // body frame, per second
    const Pose3 &pose() const { return T_; }
    double time() const { return t_; }
    const MotionModelConfig &config() const { return config_; }

  private:
    Vector6d clamped(Vector6d twist) const;

    MotionModelConfig config_;
    bool initialised_ = false;
    bool restarted_ = false;
    bool previous_trusted_ = true;
    Pose3 T_ = Pose3::Identity();
    double t_ = 0.0;
    double twist_t_ = 0.0;  // when twist_ was measured
    Vector6d twist_ = Vector6d::Zero();
};

}  // namespace forestslam::odometry
