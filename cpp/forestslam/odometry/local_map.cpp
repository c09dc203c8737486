#include "forestslam/odometry/local_map.hpp"

#include <cmath>
#include <vector>

namespace forestslam::odometry {

Points3 thinEvenly(const Eigen::Ref<const Points3> &points, int limit) {
    const Eigen::Index n = points.rows();
    if (limit <= 0 || n <= limit) return points;
    Points3 out(limit, 3);
    // The rows numpy.linspace(0, n - 1, limit).astype(int) picks.
    const double step = limit > 1 ? double(n - 1) / double(limit - 1) : 0.0;
    for (int i = 0; i < limit; ++i) out.row(i) = points.row(static_cast<Eigen::Index>(i * step));
    return out;
}

LocalMap::LocalMap(const OdometryConfig &config) : config_(config) {}

void LocalMap::add(MapFrame frame) {
    if (config_.mode == "scan_to_scan") {
        frames_.clear();
    } else if (!isKeyframe(frame)) {
        return;
    }
    frames_.push_back(std::move(frame));
    while (static_cast<int>(frames_.size()) > std::max(1, config_.local_map_keyframes))
        frames_.pop_front();
    mergeStems();
    buildCloud();
    buildSearch();
}

bool LocalMap::isKeyframe(const MapFrame &frame) const {
    if (frames_.empty()) return true;
    const Pose3 rel = frames_.back().T_world_sensor.inverse() * frame.T_world_sensor;
    const double yaw_deg = std::atan2(rel(1, 0), rel(0, 0)) * 180.0 / M_PI;
    return rel.translation().norm() >= config_.keyframe_distance_m ||
           std::abs(yaw_deg) >= config_.keyframe_yaw_deg;
}

// Newest frame first; an older stem within stem_merge_m (XY) of a kept one is the same tree.
void LocalMap::mergeStems() {
    std::vector<Eigen::Index> frame_of, row_of;
    std::vector<Eigen::Vector2d> kept;
    for (int f = static_cast<int>(frames_.size()) - 1; f >= 0; --f) {
        const Points3 &pos = frames_[f].stem_positions;
        const std::size_t kept_before = kept.size();
        for (Eigen::Index i = 0; i < pos.rows(); ++i) {
            const Eigen::Vector2d xy = pos.row(i).head<2>().transpose();
            bool is_new = true;
            for (std::size_t j = 0; j < kept_before && is_new; ++j)
                is_new = (kept[j] - xy).norm() > config_.stem_merge_m;
            if (!is_new) continue;
            frame_of.push_back(f);
            row_of.push_back(i);
            kept.push_back(xy);
        }
    }
    stem_positions_.resize(static_cast<Eigen::Index>(kept.size()), 3);
    stem_covariances_.resize(static_cast<Eigen::Index>(kept.size()), 9);
    for (std::size_t k = 0; k < kept.size(); ++k) {
        const MapFrame &frame = frames_[frame_of[k]];
        stem_positions_.row(k) = frame.stem_positions.row(row_of[k]);
        stem_covariances_.row(k) = frame.stem_covariances.row(row_of[k]);
    }
}

void LocalMap::buildCloud() {
    Eigen::Index total = 0;
    for (const auto &f : frames_) total += f.cloud.rows();
    const Eigen::Vector2d centre = frames_.back().T_world_sensor.translation().head<2>();
    Points3 near(total, 3);
    Eigen::Index n = 0;
    for (const auto &f : frames_)
        for (Eigen::Index i = 0; i < f.cloud.rows(); ++i)
            if ((f.cloud.row(i).head<2>().transpose() - centre).norm() <=
                config_.local_map_radius_m)
                near.row(n++) = f.cloud.row(i);
    near.conservativeResize(n, 3);
    if (frames_.size() > 1 && n > 0) {
        const bool fpfh = config_.method == "fpfh";
        near = registration::voxelCentroids(
            near, fpfh ? config_.registration.fpfh.voxel_m : config_.map_voxel_m);
    }
    cloud_ = std::move(near);
}

void LocalMap::buildSearch() {
    plane_.reset();
    stem_centre_.reset();
    if (cloud_.rows() == 0 || config_.method == "fpfh") return;
    if (config_.method == "stem_centre_lm")
        stem_centre_ = std::make_unique<registration::StemCentreTarget>(cloud_);
    else
        plane_ =
            std::make_unique<registration::PlaneTarget>(cloud_, config_.registration.icp.normal_k);
}

}  // namespace forestslam::odometry
