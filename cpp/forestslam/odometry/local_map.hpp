// The registration target of the tree odometry: the last keyframes (or the previous scan) in the
// world frame, as stem Gaussians (for tree matching and shape-to-shape) and as a cloud with the
// search structure the chosen method needs (point-to-plane, stem-centre LM, or none for FPFH).
#pragma once

#include <deque>
#include <memory>

#include "forestslam/odometry/odometry_config.hpp"
#include "forestslam/registration/stem_centre_lm.hpp"

namespace forestslam::odometry {

// World-frame content of one scan.
struct MapFrame {
    Pose3 T_world_sensor = Pose3::Identity();
    Points3 stem_positions;                      // (K,3) breast-height centres
    registration::Covariances stem_covariances;  // (K,9) row-major 3x3
    Points3 cloud;                               // stem + ground points (the whole scan for "fpfh")
};

class LocalMap {
  public:
    explicit LocalMap(const OdometryConfig &config);

    // The newest registered scan, world frame. In local_map mode it becomes a keyframe when it
    // is keyframe_distance_m / keyframe_yaw_deg away from the last one; scan_to_scan always.
    void add(MapFrame frame);

    bool empty() const { return cloud_.rows() == 0; }
    const Points3 &cloud() const { return cloud_; }
    const Points3 &stemPositions() const { return stem_positions_; }
    const registration::Covariances &stemCovariances() const { return stem_covariances_; }
    const registration::PlaneTarget *planeTarget() const { return plane_.get(); }
    const registration::StemCentreTarget *stemCentreTarget() const { return stem_centre_.get(); }
    std::size_t keyframes() const { return frames_.size(); }

  private:
    bool isKeyframe(const MapFrame &frame) const;
    void mergeStems();
    void buildCloud();
    void buildSearch();

    OdometryConfig config_;
    std::deque<MapFrame> frames_;
    Points3 stem_positions_ = Points3(0, 3);
    registration::Covariances stem_covariances_ = registration::Covariances(0, 9);
    Points3 cloud_ = Points3(0, 3);
    std::unique_ptr<registration::PlaneTarget> plane_;
    std::unique_ptr<registration::StemCentreTarget> stem_centre_;
};

// Rows kept evenly spread (deterministic) when there are more than `limit`.
Points3 thinEvenly(const Eigen::Ref<const Points3> &points, int limit);

}  // namespace forestslam::odometry
