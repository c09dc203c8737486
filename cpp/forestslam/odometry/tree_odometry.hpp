// LiDAR odometry from tree stems (Gupta et al. 2023, Section 3.3) and its baselines, one scan at
// a time: constant-velocity prediction -> deskew -> perception (stems + ground) -> tree matching
// -> shape-to-shape registration -> point-to-plane ICP -> local map, all in the world frame (the
// first scan's sensor frame at its stamp). Fewer than min_stems matched stems (or a failed
// registration): ICP with the velocity prior and the pose marked degraded; with nothing usable,
// the prediction itself. It never stops on a bad scan.
#pragma once

#include <limits>
#include <map>
#include <string>

#include "forestslam/odometry/local_map.hpp"
#include "forestslam/odometry/motion_model.hpp"
#include "forestslam/odometry/odometry_config.hpp"
#include "forestslam/perception/detector.hpp"

namespace forestslam::odometry {

// One LiDAR sweep. intensity, ring and time are empty or hold one value per point; time is in
// seconds after the stamp (per-point time of a spinning sensor).
struct LidarScan {
    double stamp = 0.0;
    Points3 points = Points3(0, 3);
    Eigen::VectorXd intensity;
    Eigen::VectorXi ring;
    Eigen::VectorXd time;
};

// What the odometry needs to know about the sensor (from a sensor profile).
struct OdometrySensor {
    perception::SensorGeometry geometry;
    std::string kind = "spinning";  // spinning, solid_state, tls, map
    double intensity_threshold = std::numeric_limits<double>::quiet_NaN();  // NaN: none
};

struct OdometryResult {
    double stamp = 0.0;
    Pose3 T_world_sensor = Pose3::Identity();  // at the stamp
    // (3,3) over x, y, yaw of this scan's registration as a body-frame (current sensor frame)
    // perturbation; usable as the covariance of the step from the previous scan.
    Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
    // (6,6) body-frame (tx, ty, tz, rx, ry, rz) when a registration produced the pose.
    Matrix6d covariance6 = Matrix6d::Zero();
    bool has_covariance6 = false;
    bool degraded = false;  // the pose rests on the velocity prior
    std::string method;     // first, trees, icp, icp_prior, fpfh, stem_centre_lm, prediction
    int matched_stems = 0;
    perception::Detection detection;  // the scan's stems and ground, sensor frame at the stamp
    StampCheck stamp_check;           // the motion model restarted (gap or jump back)?
    std::string perception_error;     // non-empty: perception failed, no stems this scan
    std::map<std::string, double> timing_ms;  // per stage, wall clock
    std::map<std::string, double> cpu_ms;     // per stage, process CPU
};

class TreeOdometry {
  public:
    TreeOdometry(const OdometrySensor &sensor, const OdometryConfig &config = {},
                 const perception::PerceptionConfig &perception = {});

    OdometryResult registerScan(const LidarScan &scan);

    const ConstantVelocityModel &motionModel() const { return motion_; }
    const LocalMap &localMap() const { return map_; }
    const OdometryConfig &config() const { return config_; }
    int scans() const { return scans_; }

  private:
    struct Work;  // one scan's intermediate state
    struct Registration {
        Pose3 T = Pose3::Identity();
        Matrix6d covariance = Matrix6d::Zero();  // world-frame left perturbation
        bool degraded = false;
        std::string method;
        int matched = 0;
    };

    void predict(Work &work);
    double midSweepTime(const LidarScan &scan) const;
    bool deskews(const LidarScan &scan) const;
    Points3 deskew(const LidarScan &scan, double t_mid) const;
    perception::Detection detect(const LidarScan &scan, const Points3 &points, Work &work) const;
    void selectSources(Work &work) const;
    Registration firstScan() const;
    Registration registerOnMap(Work &work) const;
    Registration registerTrees(Work &work) const;
    Registration registerFpfh(Work &work) const;
    Registration registerStemCentres(Work &work) const;
    Registration accept(const registration::RegistrationResult *result, const Pose3 &T_pred,
                        bool degraded, const std::string &method, int matched) const;
    void updateMap(const Work &work, const Registration &reg);
    OdometryResult output(Work &work, const Registration &reg);

    OdometrySensor sensor_;
    OdometryConfig config_;
    perception::PerceptionConfig perception_;
    ConstantVelocityModel motion_;
    LocalMap map_;
    Pose3 W_ = Pose3::Identity();  // output world (first stamp) <- state world (first mid-sweep)
    double t_mid0_ = 0.0;
    int scans_ = 0;
};

// Stems, ground and the other point-like fields of a detection expressed in another frame.
void transformDetection(perception::Detection &detection, const Pose3 &T);

}  // namespace forestslam::odometry
