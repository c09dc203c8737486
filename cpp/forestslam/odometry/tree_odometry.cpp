#include "forestslam/odometry/tree_odometry.hpp"

#include <time.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "forestslam/features/dog_keypoints.hpp"
#include "forestslam/registration/tree_correspondences.hpp"

namespace forestslam::odometry {
namespace {

constexpr double kDeg = M_PI / 180.0;

double processCpuMs() {
    timespec ts{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

double wallMs() {
    using namespace std::chrono;
    return duration<double, std::milli>(steady_clock::now().time_since_epoch()).count();
}

// Wall and process-CPU milliseconds per named stage.
struct StageClock {
    double wall = wallMs(), cpu = processCpuMs();
    void lap(OdometryResult &out, const std::string &name) {
        const double w = wallMs(), c = processCpuMs();
        out.timing_ms[name] += w - wall;
        out.cpu_ms[name] += c - cpu;
        wall = w;
        cpu = c;
    }
};

// T = P L: P rotation about z plus the translation, L roll and pitch only.
std::pair<Pose3, Pose3> levelledPlanar(const Pose3 &T) {
    const double yaw = std::atan2(T(1, 0), T(0, 0));
    Pose3 P = Pose3::Identity();
    P.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    P.translation() = T.translation();
    Pose3 L = Pose3::Identity();
    L.linear() = P.linear().transpose() * T.linear();
    return {P, L};
}

registration::Covariances rotateCovariances(const Eigen::Matrix3d &R,
                                            const Eigen::Ref<const registration::Covariances> &c) {
    registration::Covariances out(c.rows(), 9);
    for (Eigen::Index i = 0; i < c.rows(); ++i) {
        const Eigen::Matrix3d C =
            Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(c.row(i).data());
        Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(out.row(i).data()) =
            R * C * R.transpose();
    }
    return out;
}

// x, y, yaw covariance of a world-frame (left) perturbation -> current sensor frame.
Eigen::Matrix3d worldToBodyPlanar(const Matrix6d &cov6, const Pose3 &T) {
    const int idx[3] = {0, 1, 5};
    Eigen::Matrix3d cov;
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) cov(r, c) = cov6(idx[r], idx[c]);
    const double n = std::hypot(T(0, 0), T(1, 0));
    Eigen::Matrix2d Rt;
    Rt << T(0, 0), T(1, 0), -T(1, 0), T(0, 0);
    if (n > 0) Rt /= n;
    Eigen::Matrix3d A = Eigen::Matrix3d::Identity();
    A.topLeftCorner<2, 2>() = Rt;
    A.topRightCorner<2, 1>() = Rt * Eigen::Vector2d(-T(1, 3), T(0, 3));
    return A * cov * A.transpose();
}

Matrix6d worldToBody6(const Matrix6d &cov6, const Pose3 &T) {
    const Eigen::Matrix3d Rt = T.linear().transpose();
    const Eigen::Vector3d t = T.translation();
    Eigen::Matrix3d tx;
    tx << 0, -t.z(), t.y(), t.z(), 0, -t.x(), -t.y(), t.x(), 0;
    Matrix6d A = Matrix6d::Zero();
    A.topLeftCorner<3, 3>() = Rt;
    A.topRightCorner<3, 3>() = -Rt * tx;
    A.bottomRightCorner<3, 3>() = Rt;
    return A * cov6 * A.transpose();
}

void checkScan(const LidarScan &scan) {
    const Eigen::Index n = scan.points.rows();
    auto check = [n](Eigen::Index size, const char *name) {
        if (size != 0 && size != n)
            throw std::invalid_argument(std::string("scan ") + name + " has " +
                                        std::to_string(size) + " values for " + std::to_string(n) +
                                        " points");
    };
    if (!std::isfinite(scan.stamp)) throw std::invalid_argument("scan stamp is not finite");
    check(scan.intensity.size(), "intensity");
    check(scan.ring.size(), "ring");
    check(scan.time.size(), "time");
}

}  // namespace

void validate(const OdometryConfig &c) {
    auto need = [](bool ok, const std::string &what) {
        if (!ok) throw std::invalid_argument("odometry config: " + what);
    };
    need(c.method == "trees" || c.method == "icp" || c.method == "fpfh" ||
             c.method == "stem_centre_lm",
         "method '" + c.method + "' unknown; choose one of trees, icp, fpfh, stem_centre_lm");
    need(c.mode == "local_map" || c.mode == "scan_to_scan",
         "mode '" + c.mode + "' unknown; choose one of local_map, scan_to_scan");
    need(c.min_stems >= 1, "min_stems must be >= 1");
    need(c.source_voxel_m > 0 && c.map_voxel_m > 0, "source_voxel_m and map_voxel_m must be > 0");
    need(c.max_source_points >= 3 && c.fpfh_max_points >= 3,
         "max_source_points and fpfh_max_points must be >= 3");
    need(c.local_map_keyframes >= 1, "local_map_keyframes must be >= 1");
    need(c.local_map_radius_m > 0, "local_map_radius_m must be > 0");
    need(c.prior_sigma_m > 0 && c.prior_sigma_deg > 0, "prior sigmas must be > 0");
    need(c.registration.icp.max_iterations >= 1, "registration.icp.max_iterations must be >= 1");
    need(c.registration.icp.normal_k >= 3, "registration.icp.normal_k must be >= 3");
    need(c.registration.trees.gate_m > 0, "registration.trees.gate_m must be > 0");
    need(c.registration.trees.ratio > 0 && c.registration.trees.ratio <= 1,
         "registration.trees.ratio must be in (0, 1]");
    motionModelConfig(c);
}

MotionModelConfig motionModelConfig(const OdometryConfig &c) {
    MotionModelConfig m;
    m.max_gap_s = c.max_stamp_gap_s;
    m.max_speed_mps = c.max_speed_mps;
    m.max_turn_rate_dps = c.max_turn_rate_dps;
    if (!(m.max_gap_s > 0) || !(m.max_speed_mps > 0) || !(m.max_turn_rate_dps > 0))
        throw std::invalid_argument(
            "odometry config: max_stamp_gap_s, max_speed_mps and max_turn_rate_dps must be > 0");
    return m;
}

void transformDetection(perception::Detection &det, const Pose3 &T) {
    const Eigen::Matrix3d R = T.linear();
    for (auto &s : det.stems) {
        const Eigen::Vector3d base = T * Eigen::Vector3d(s.breast.x(), s.breast.y(), s.base_z);
        s.points = transformPoints(T, s.points);
        if (s.normals.rows()) s.normals = s.normals * R.transpose();
        s.breast = T * s.breast;
        s.base_z = base.z();
        s.shape.mean = T * s.shape.mean;
        s.shape.cov = R * s.shape.cov * R.transpose();
        s.shape.axis = R * s.shape.axis;
        s.diameter.centre = T * s.diameter.centre;
    }
    det.ground = transformPoints(T, det.ground);
    det.up = R * det.up;
}

struct TreeOdometry::Work {
    explicit Work(const LidarScan &s) : scan(s) {}
    const LidarScan &scan;
    OdometryResult out;
    StageClock clock;
    const StageClock start = clock;
    double t_mid = 0.0, t_ref = 0.0;
    Pose3 T_pred = Pose3::Identity();
    Points3 points;                 // deskewed
    Points3 cloud = Points3(0, 3);  // registration source: stem + ground (whole scan: fpfh)
    Points3 stem_positions = Points3(0, 3);
    registration::Covariances stem_covariances = registration::Covariances(0, 9);
};

TreeOdometry::TreeOdometry(const OdometrySensor &sensor, const OdometryConfig &config,
                           const perception::PerceptionConfig &perception)
    : sensor_(sensor),
      config_(config),
      perception_(perception),
      motion_(motionModelConfig(config)),
      map_(config) {
    validate(config_);
}

// The table of contents: every stage of one scan, in order.
OdometryResult TreeOdometry::registerScan(const LidarScan &scan) {
    checkScan(scan);
    Work work(scan);
    predict(work);
    work.points = deskew(scan, work.t_mid);
    work.clock.lap(work.out, "deskew");
    work.out.detection = detect(scan, work.points, work);
    work.clock.lap(work.out, "perception");
    selectSources(work);
    const Registration reg = motion_.initialised() ? registerOnMap(work) : firstScan();
    updateMap(work, reg);
    work.clock.lap(work.out, "map");
    return output(work, reg);
}

// Scans are deskewed to, and registered at, the middle of their sweep: a velocity error then
// distorts the scan symmetrically and does not feed back into the next pose.
void TreeOdometry::predict(Work &work) {
    work.t_mid = midSweepTime(work.scan);
    work.t_ref = work.scan.stamp + work.t_mid;
    work.out.stamp_check = motion_.beginScan(work.t_ref);
    work.T_pred = motion_.predict(work.t_ref);
}

bool TreeOdometry::deskews(const LidarScan &scan) const {
    return config_.deskew && sensor_.kind == "spinning" && scan.time.size() > 0 &&
           scan.points.rows() > 0;
}

double TreeOdometry::midSweepTime(const LidarScan &scan) const {
    if (!deskews(scan)) return 0.0;
    double lo = INFINITY, hi = -INFINITY;
    for (Eigen::Index i = 0; i < scan.time.size(); ++i)
        if (std::isfinite(scan.time(i))) {
            lo = std::min(lo, scan.time(i));
            hi = std::max(hi, scan.time(i));
        }
    return lo <= hi ? 0.5 * (lo + hi) : 0.0;
}

Points3 TreeOdometry::deskew(const LidarScan &scan, double t_mid) const {
    if (!deskews(scan) || !motion_.initialised()) return scan.points;
    return motion_.deskew(scan.points, scan.time.array() - t_mid);
}

perception::Detection TreeOdometry::detect(const LidarScan &scan, const Points3 &points,
                                           Work &work) const {
    if (points.rows() == 0) return {};
    const auto &g = sensor_.geometry;
    // A ring field outside the sensor's rows is not trusted: elevation angles are used instead.
    Eigen::VectorXi ring = scan.ring;
    if (ring.size() &&
        (!g.has_range_image || ring.minCoeff() < 0 || ring.maxCoeff() >= g.image_rows))
        ring.resize(0);
    try {
        return perception::detectStems(points, scan.intensity, ring, g, sensor_.kind != "map",
                                       perception_);
    } catch (const std::exception &e) {
        work.out.perception_error = e.what();
        return {};
    }
}

void TreeOdometry::selectSources(Work &work) const {
    const auto &stems = work.out.detection.stems;
    Eigen::Index total = work.out.detection.ground.rows();
    for (const auto &s : stems) total += s.points.rows();
    Points3 all(total, 3);
    Eigen::Index n = 0;
    for (const auto &s : stems) {
        all.middleRows(n, s.points.rows()) = s.points;
        n += s.points.rows();
    }
    all.bottomRows(work.out.detection.ground.rows()) = work.out.detection.ground;
    all = finiteRows(all);
    if (all.rows())
        work.cloud = thinEvenly(registration::voxelCentroids(all, config_.source_voxel_m),
                                config_.max_source_points);
    if (config_.method == "fpfh" && work.points.rows())
        work.cloud =
            thinEvenly(registration::voxelCentroids(work.points, config_.registration.fpfh.voxel_m),
                       config_.fpfh_max_points);
    // Stem Gaussians for shape-to-shape: the breast-height centre (less view-dependent than
    // the mean of the visible arc) with the covariance of the stem points.
    work.stem_positions.resize(static_cast<Eigen::Index>(stems.size()), 3);
    work.stem_covariances.resize(static_cast<Eigen::Index>(stems.size()), 9);
    Eigen::Index k = 0;
    for (const auto &s : stems) {
        if (!s.breast.allFinite() || !s.shape.cov.allFinite()) continue;
        work.stem_positions.row(k) = s.breast.transpose();
        Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(
            work.stem_covariances.row(k).data()) = s.shape.cov;
        ++k;
    }
    work.stem_positions.conservativeResize(k, 3);
    work.stem_covariances.conservativeResize(k, 9);
}

TreeOdometry::Registration TreeOdometry::firstScan() const {
    Registration reg;
    reg.method = "first";
    return reg;
}

TreeOdometry::Registration TreeOdometry::registerOnMap(Work &work) const {
    if (config_.method == "fpfh") return registerFpfh(work);
    if (config_.method == "stem_centre_lm") return registerStemCentres(work);
    return registerTrees(work);
}

// Stems matched under the prediction and registered shape to shape over x, y, yaw (levelled
// by the predicted roll / pitch), then point-to-plane ICP on stem + ground points. Too few
// consistent stems: ICP pulled towards the prediction by the velocity prior. "icp": the ICP
// from the prediction alone.
TreeOdometry::Registration TreeOdometry::registerTrees(Work &work) const {
    const auto &rc = config_.registration;
    Pose3 T_init = work.T_pred;
    bool use_prior = false;
    int matched = 0;
    if (config_.method == "trees") {
        const auto [P, L] = levelledPlanar(work.T_pred);
        const Points3 source = transformPoints(L, work.stem_positions);
        const Points3 &target = map_.stemPositions();
        std::vector<std::pair<int, int>> pairs;
        if (source.rows() && target.rows())
            pairs = registration::matchTrees(source, target, P, rc.trees.gate_m, rc.trees.ratio);
        work.clock.lap(work.out, "match");
        matched = static_cast<int>(pairs.size());
        use_prior = matched < config_.min_stems;
        if (!use_prior) {
            const registration::RegistrationResult shape = registration::registerShapes(
                source, rotateCovariances(L.linear(), work.stem_covariances), target,
                map_.stemCovariances(), pairs, P, rc.shape);
            work.clock.lap(work.out, "shape");
            use_prior = shape.inliers < config_.min_stems;
            if (!use_prior) {
                T_init = shape.T_target_source * L;
                T_init.translation().z() = work.T_pred.translation().z();
                matched = shape.inliers;
            }
        }
    }
    registration::RegistrationResult icp;
    const bool has_icp = map_.planeTarget() && work.cloud.rows();
    if (has_icp) {
        Matrix6d info = Matrix6d::Zero();
        if (use_prior) {
            info.diagonal() << Eigen::Vector3d::Constant(1.0 / std::pow(config_.prior_sigma_m, 2)),
                Eigen::Vector3d::Constant(1.0 / std::pow(config_.prior_sigma_deg * kDeg, 2));
        }
        icp = registration::icpPointToPlane(*map_.planeTarget(), work.cloud, T_init, rc.icp, info,
                                            use_prior ? work.T_pred : T_init);
    }
    work.clock.lap(work.out, "icp");
    const std::string name = use_prior ? "icp_prior" : config_.method;
    const bool degraded = use_prior && config_.method == "trees";
    return accept(has_icp ? &icp : nullptr, work.T_pred, degraded, name, matched);
}

TreeOdometry::Registration TreeOdometry::registerFpfh(Work &work) const {
    registration::RegistrationResult result;
    const bool ran = work.cloud.rows() && map_.cloud().rows();
    if (ran) {
        registration::FpfhConfig fpfh = config_.registration.fpfh;
        fpfh.icp = config_.registration.icp;
        result =
            forestslam::registration::registerFpfh(work.cloud, map_.cloud(), work.T_pred, fpfh);
    }
    work.clock.lap(work.out, "fpfh");
    return accept(ran ? &result : nullptr, work.T_pred, false, "fpfh", 0);
}

// Stem-centre LM (Shao et al.): stem centres with their radius and DoG keypoints as features.
TreeOdometry::Registration TreeOdometry::registerStemCentres(Work &work) const {
    registration::StemCentreLmResult result;
    const registration::StemCentreTarget *target = map_.stemCentreTarget();
    if (target) {
        std::vector<int> rows;
        const auto &stems = work.out.detection.stems;
        for (std::size_t i = 0; i < stems.size(); ++i)
            if (std::isfinite(stems[i].diameter.dbh) && stems[i].breast.allFinite())
                rows.push_back(static_cast<int>(i));
        Points3 centres(static_cast<Eigen::Index>(rows.size()), 3);
        Eigen::VectorXd radii(static_cast<Eigen::Index>(rows.size()));
        for (std::size_t k = 0; k < rows.size(); ++k) {
            centres.row(k) = stems[rows[k]].breast.transpose();
            radii(k) = 0.5 * stems[rows[k]].diameter.dbh;
        }
        const Points3 real = features::detectDogKeypoints(work.points).points;
        result = registration::registerStemCentreLm(*target, centres, radii, real, work.T_pred);
    }
    work.clock.lap(work.out, "stem_centre_lm");
    return accept(target ? &result : nullptr, work.T_pred, false, "stem_centre_lm", 0);
}

// A registration is kept unless it failed or jumped away from the prediction.
TreeOdometry::Registration TreeOdometry::accept(const registration::RegistrationResult *result,
                                                const Pose3 &T_pred, bool degraded,
                                                const std::string &method, int matched) const {
    Matrix6d prior = Matrix6d::Zero();
    prior.diagonal() << Eigen::Vector3d::Constant(std::pow(config_.prior_sigma_m, 2)),
        Eigen::Vector3d::Constant(std::pow(config_.prior_sigma_deg * kDeg, 2));
    Registration prediction{T_pred, prior, true, "prediction", matched};
    if (!result || result->inliers == 0) return prediction;
    const Pose3 &T = result->T_target_source;
    if (!T.matrix().allFinite()) return prediction;
    const Pose3 d = T_pred.inverse() * T;
    const double cos_turn = std::clamp((d.linear().trace() - 1.0) / 2.0, -1.0, 1.0);
    if (d.translation().norm() > config_.max_correction_m ||
        std::acos(cos_turn) > config_.max_correction_deg * kDeg)
        return prediction;
    Registration reg{T, result->covariance, degraded, method, matched};
    reg.degraded = degraded || (result->degenerate && method != "fpfh") ||
                   !(result->converged || result->iterations > 0);
    if (result->degenerate) reg.covariance += prior;  // the prior carried the unobserved
    return reg;
}

void TreeOdometry::updateMap(const Work &work, const Registration &reg) {
    motion_.update(work.t_ref, reg.T);
    MapFrame frame;
    frame.T_world_sensor = reg.T;
    frame.stem_positions = transformPoints(reg.T, work.stem_positions);
    frame.stem_covariances = rotateCovariances(reg.T.linear(), work.stem_covariances);
    frame.cloud = transformPoints(reg.T, work.cloud);
    map_.add(std::move(frame));
}

// From the mid-sweep frame to the frame at the stamp; stems move along so that they sit in the
// output pose's frame.
OdometryResult TreeOdometry::output(Work &work, const Registration &reg) {
    const Pose3 T_mid_stamp =
        work.t_mid != 0.0 ? twistToPose(-motion_.twist() * work.t_mid) : Pose3::Identity();
    if (scans_ == 0) {
        t_mid0_ = work.t_mid;
    } else if (scans_ == 1) {
        // The state's world frame is the first scan's mid-sweep frame; now that the velocity is
        // known, outputs are re-anchored to its frame at the stamp.
        W_ = twistToPose(motion_.twist() * t_mid0_);
    }
    const Pose3 T_out = W_ * reg.T * T_mid_stamp;
    if (work.t_mid != 0.0) transformDetection(work.out.detection, T_mid_stamp.inverse());
    OdometryResult &out = work.out;
    out.stamp = work.scan.stamp;
    out.T_world_sensor = T_out;
    out.covariance = worldToBodyPlanar(reg.covariance, T_out);
    out.has_covariance6 = reg.method != "first" && reg.method != "prediction";
    if (out.has_covariance6) out.covariance6 = worldToBody6(reg.covariance, T_out);
    out.degraded = reg.degraded;
    out.method = reg.method;
    out.matched_stems = reg.matched;
    out.timing_ms["total"] = wallMs() - work.start.wall;
    out.cpu_ms["total"] = processCpuMs() - work.start.cpu;
    out.timing_ms["cpu_total"] = out.cpu_ms["total"];
    ++scans_;
    return std::move(out);
}

}  // namespace forestslam::odometry
