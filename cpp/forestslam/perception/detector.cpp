#include "forestslam/perception/detector.hpp"

#include <pcl/console/print.h>

#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>

#include "forestslam/perception/preprocess.hpp"
#include "forestslam/perception/segmentation.hpp"

namespace forestslam::perception {
namespace {

using Clock = std::chrono::steady_clock;

// CPU time of this thread: the cost on one core, whatever else the machine is doing.
double threadCpuMs() {
    timespec ts{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return 1e3 * static_cast<double>(ts.tv_sec) + 1e-6 * static_cast<double>(ts.tv_nsec);
}

struct StageClock {
    Clock::time_point wall = Clock::now();
    double cpu = threadCpuMs();
    void lap(Detection &det, const std::string &stage) {
        const auto now = Clock::now();
        const double c = threadCpuMs();
        det.timing_ms[stage] = std::chrono::duration<double, std::milli>(now - wall).count();
        det.cpu_ms[stage] = c - cpu;
        wall = now;
        cpu = c;
    }
};

}  // namespace

Eigen::Vector3d groundNormal(const Eigen::Ref<const Points3> &ground) {
    if (ground.rows() < 10) return Eigen::Vector3d::UnitZ();
    const Eigen::RowVector3d mean = ground.colwise().mean();
    const Eigen::MatrixXd c = ground.rowwise() - mean;
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(c.transpose() * c);
    Eigen::Vector3d n = eig.eigenvectors().col(0);
    if (n.z() < 0) n = -n;
    // A cloud of ground points that is not a plane (a slope + bank) or is steep: keep +z.
    if (n.z() < std::cos(0.5236) || !n.allFinite()) return Eigen::Vector3d::UnitZ();
    return n;
}

Detection detectStems(const Eigen::Ref<const Points3> &points,
                      const Eigen::Ref<const Eigen::VectorXd> &intensity,
                      const Eigen::Ref<const Eigen::VectorXi> &ring, const SensorGeometry &sensor,
                      bool scan_centred, const PerceptionOptions &opt) {
    // PCL reports every RANSAC without a model on stderr; a stem without a cylinder is normal.
    pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS);
    Detection det;
    det.input_points = static_cast<int>(points.rows());
    StageClock clock;
    const auto t0 = clock.wall;
    const double c0 = clock.cpu;

    // 1. Finite rows within the intensity threshold.
    std::vector<int> keep = intensityFilter(intensity, opt.intensity_threshold, points.rows());
    det.after_intensity = static_cast<int>(keep.size());
    std::vector<int> finite;
    finite.reserve(keep.size());
    for (int i : keep)
        if (points.row(i).allFinite()) finite.push_back(i);
    det.finite_points = static_cast<int>(finite.size());
    Points3 pts = selectRows(points, finite);
    // Map clouds come in projected coordinates (UTM: 3.8e6 m): PCL works in float, so work
    // relative to a local origin and add it back to the outputs.
    Eigen::RowVector3d origin = Eigen::RowVector3d::Zero();
    if (!scan_centred && pts.rows() > 0) {
        origin = pts.colwise().minCoeff().array().floor().matrix();
        pts.rowwise() -= origin;
    }
    Eigen::VectorXi ring_sel;
    if (ring.size() == points.rows()) {
        ring_sel.resize(static_cast<Eigen::Index>(finite.size()));
        for (size_t k = 0; k < finite.size(); ++k)
            ring_sel(static_cast<Eigen::Index>(k)) = ring(finite[k]);
    }
    clock.lap(det, "intensity");

    // 2. Ground.
    GroundOptions gopt = opt.ground;
    if (!scan_centred) gopt.max_range_m = 0;
    GroundSegmentation gs = segmentGround(pts, gopt);
    det.ground_points = gs.ground_count;
    det.ground = thinGround(pts, gs.is_ground, opt.ground_voxel_m);
    det.up = groundNormal(det.ground);
    clock.lap(det, "ground");

    // 3. Adaptive normals and filter on the non-ground points.
    std::vector<int> candidates;
    candidates.reserve(finite.size());
    const double range_max = scan_centred ? opt.segmentation.max_range_m : 0.0;
    for (Eigen::Index i = 0; i < pts.rows(); ++i) {
        if (gs.is_ground[static_cast<size_t>(i)]) continue;
        if (range_max > 0 && std::hypot(pts(i, 0), pts(i, 1)) > range_max) continue;
        candidates.push_back(static_cast<int>(i));
    }
    NormalFilterOptions fopt = opt.filter;
    if (!scan_centred) {
        fopt.adaptive = false;
        fopt.voxel_m = std::max(fopt.voxel_m, fopt.map_voxel_m);
    }
    const NormalFilterResult nf = normalFilter(pts, candidates, sensor.theta_v_rad, fopt,
                                               gs.grid.z.size() > 0 ? &gs.grid : nullptr);
    const Points3 filtered = selectRows(pts, nf.kept);
    det.filtered_points = static_cast<int>(filtered.rows());
    clock.lap(det, "normals");

    // 4. Coarse clusters: range image for single scans, 3D otherwise.
    const SegmentationOptions &so = opt.segmentation;
    Clusters coarse;
    if (sensor.has_range_image && scan_centred) {
        Eigen::VectorXi ring_f;
        if (ring_sel.size() > 0) {
            ring_f.resize(static_cast<Eigen::Index>(nf.kept.size()));
            for (size_t k = 0; k < nf.kept.size(); ++k)
                ring_f(static_cast<Eigen::Index>(k)) = ring_sel(nf.kept[k]);
        }
        const RangeImageProjection proj = projectToRangeImage(filtered, ring_f, sensor);
        coarse = rangeImageClusters(filtered, proj, sensor, so, std::max(2, so.min_points / 2));
    } else {
        coarse =
            euclideanClusters(filtered, so.euclidean_tolerance_m, std::max(2, so.min_points / 2));
    }
    det.coarse_clusters = static_cast<int>(coarse.size());
    clock.lap(det, "clustering");

    // 5. DBSCAN refinement and SVD classification.
    Clusters stems;
    for (const auto &c : coarse) {
        const double eps = (sensor.has_range_image && scan_centred)
                               ? adaptiveEps(filtered, c, sensor.theta_v_rad, so)
                               : so.map_dbscan_eps_m;
        for (auto &sub : dbscan(filtered, c, eps, so.dbscan_min_neighbours)) {
            ++det.refined_clusters;
            const ClusterShape s = clusterShape(filtered, sub, det.up);
            if (isStem(s, static_cast<int>(sub.size()), so)) stems.push_back(std::move(sub));
        }
    }
    stems = mergeStemClusters(filtered, stems, so);
    clock.lap(det, "classification");

    // 6. Per stem: shape, local ground, breast-height centre and diameter.
    SilhouetteSensor silhouette;
    silhouette.vertical_angles_rad = sensor.vertical_angles_rad;
    silhouette.azimuth_step_rad =
        sensor.azimuth_step_rad > 0
            ? sensor.azimuth_step_rad
            : (sensor.image_cols > 0 ? sensor.horizontal_fov_rad / sensor.image_cols : 0.0);
    DiameterOptions dopt = opt.diameter;
    if (!scan_centred)
        dopt.min_arc_coverage = std::max(dopt.min_arc_coverage, dopt.map_min_arc_coverage);
    const bool use_silhouette = opt.diameter.silhouette && scan_centred && sensor.has_range_image &&
                                !silhouette.vertical_angles_rad.empty();
    for (const auto &rows : stems) {
        Stem st;
        st.points = selectRows(filtered, rows);
        st.normals = selectRows(nf.normals, rows);
        st.shape = clusterShape(filtered, rows, det.up);
        if (!isStem(st.shape, static_cast<int>(rows.size()), so)) continue;  // merged oddly
        const Eigen::Vector2d xy = st.shape.mean.head<2>();
        double base = localGroundHeight(det.ground, xy, so.ground_search_m);
        if (!std::isfinite(base))
            base = localGroundHeight(det.ground, xy, 2.0 * so.ground_search_m);
        if (!std::isfinite(base)) base = gs.grid.heightAt(xy.x(), xy.y());
        // In the blind circle around the sensor: the plane of the ground seen farther out.
        if (!std::isfinite(base)) base = planeGroundHeight(det.ground, xy, 12.0);
        st.ground_found = std::isfinite(base);
        if (!st.ground_found) base = st.points.col(2).minCoeff();
        st.base_z = base;
        st.diameter = estimateDiameter(st.points, st.normals, base, det.up, dopt,
                                       use_silhouette ? &silhouette : nullptr);
        if (st.diameter.centre.allFinite()) {
            st.breast = st.diameter.centre;
        } else {
            // No accepted fit: the principal axis at breast height.
            const double zb = base + 0.5 * (opt.diameter.band_low_m + opt.diameter.band_high_m);
            const Eigen::Vector3d &a = st.shape.axis;
            st.breast = st.shape.mean + a * ((zb - st.shape.mean.z()) / std::max(a.z(), 0.2));
        }
        det.stems.push_back(std::move(st));
    }
    for (size_t k = 0; k < det.stems.size(); ++k) {
        Stem &st = det.stems[k];
        st.id = static_cast<int>(k);
        if (origin.isZero()) continue;
        st.points.rowwise() += origin;
        st.shape.mean += origin.transpose();
        st.breast += origin.transpose();
        st.base_z += origin.z();
        st.diameter.centre += origin.transpose();
        st.diameter.circle.centre += origin.transpose();
        st.diameter.cylinder.centre += origin.transpose();
    }
    if (!origin.isZero()) det.ground.rowwise() += origin;
    clock.lap(det, "diameter");
    det.timing_ms["total"] = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    det.cpu_ms["total"] = threadCpuMs() - c0;
    return det;
}

}  // namespace forestslam::perception
