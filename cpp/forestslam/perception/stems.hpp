// Stem classification from the SVD of each refined cluster, merging of the pieces of one tree,
// per-stem properties (mean, covariance, axis, base height) and the stem diameter at breast
// height (PCL SAC cylinder and the robust circle fit, the better by quality).
#pragma once

#include <Eigen/Core>
#include <limits>
#include <vector>

#include "forestslam/common/types.hpp"
#include "forestslam/perception/config.hpp"
#include "forestslam/perception/segmentation.hpp"

namespace forestslam::perception {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Shape of one cluster from the SVD of its centred points.
struct ClusterShape {
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
    Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();     // principal axis, pointing up
    Eigen::Vector3d singular = Eigen::Vector3d::Zero();  // s0 >= s1 >= s2 (sqrt of eigenvalues)
    double length = 0;                                   // extent along the axis
    double width = 0;                                    // extent along the second axis
    double axis_angle = 0;                               // angle between axis and `up`
};
ClusterShape clusterShape(const Eigen::Ref<const Points3> &points, const std::vector<int> &rows,
                          const Eigen::Vector3d &up);

// The paper's heuristics: count, length, angle to up, s0/s1, plus a width cap.
bool isStem(const ClusterShape &shape, int count, const SegmentationConfig &options);

// Union of stem clusters whose XY means are closer than options.merge_xy_m.
Clusters mergeStemClusters(const Eigen::Ref<const Points3> &points, const Clusters &stems,
                           const SegmentationConfig &options);

// One diameter estimate with its quality (evaluated on the same breast-height band points).
struct DiameterFit {
    bool valid = false;
    double radius = kNaN;
    Eigen::Vector3d centre = Eigen::Vector3d::Constant(kNaN);  // at breast height
    Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();
    int inliers = 0;
    double rms_m = kNaN;
    double arc_coverage = 0;
    double score = 0;          // inlier ratio * arc coverage / max(rms, 5 mm): larger is better
    double radius_std = kNaN;  // expected error of the radius (see StemDiameter::dbh_std)
    // Silhouette only: scan lines left out because they span more than one object (returns
    // behind the front of the stem their width implies: a cluster of neighbouring stems).
    int multi_object_lines = 0;
};

// What the silhouette estimate needs: the points are seen from the origin (a single scan) by
// beams at these elevations, `azimuth_step_rad` apart.
struct SilhouetteSensor {
    double azimuth_step_rad = 0.0;
    std::vector<double> vertical_angles_rad;
};

// One scan's view of a stem for the silhouette: the sensor's sampling and every return of the
// stem in that scan. The stem's other points may be thinned (the normal filter keeps one point
// per voxel, which drops the outermost returns of a silhouette where returns are closer than a
// voxel); an empty `points` means the stem's own points. `occluders`: other returns of the
// scan around the stem's bearing (any range); a scan line whose edge return has one of them
// in the next beam and nearer than the stem is cut by what stands in front, not by the stem's
// edge, and is left out of the silhouette. `beyond`: the other returns of the scan around the
// stem's bearing farther than its nearest return (any range); a scan line with returns behind
// the front of the stem its width implies sees through it, so it spans more than one object
// and is left out (empty: the stem's own returns are tested).
struct SilhouetteView {
    SilhouetteSensor sensor;
    Points3 points = Points3(0, 3);
    Points3 occluders = Points3(0, 3);
    Points3 beyond = Points3(0, 3);
};

// Rows of `candidates` (returns of the same scan, seen from the origin) on the surface of the stem
// whose returns are `stem`: within the bearings the stem's returns span and at their depth (no
// nearer than the nearest, no farther than the farthest, 0.15 m of margin: what stands in front
// is nearer, what lies behind is hidden inside the span). Whatever their intensity: a Lambertian
// bark is brightest where it faces the sensor, and no intensity threshold separates it from
// foliage under every sensor gain and intensity model; geometry does.
std::vector<int> onStemSurface(const Eigen::Ref<const Points3> &stem,
                               const Eigen::Ref<const Points3> &candidates,
                               const SilhouetteSensor &sensor);

struct StemDiameter {
    // circle: robust fit of the breast-height band; cylinder: PCL SAC cylinder; silhouette: the
    // stem's angular width per scan line seen from the sensor, r = d sin(w/2) / (1 - sin(w/2))
    // (insensitive to range noise, which makes partial-arc fits uncertain).
    DiameterFit circle, cylinder, silhouette;
    // 0 none accepted, 1 circle, 2 cylinder (in a single scan: its centre only, dbh NaN: see
    // chooseDiameter), 3 silhouette
    int method = 0;
    double dbh = kNaN;
    // Expected error (1 sigma) of dbh. Silhouette: the angular sampling (each edge of the
    // width falls anywhere within one azimuth step, and every scan line shares the same
    // azimuths: range * step / sqrt(6)) and the standard error of the lines' median;
    // circle / cylinder: the fit's covariance, RMS residual^2 (J^T J)^-1, on the band.
    double dbh_std = kNaN;
    Eigen::Vector3d centre = Eigen::Vector3d::Constant(kNaN);
    int band_points = 0;
};

// Diameter of one stem. `normals` (same rows as `points`, may be empty: then no cylinder; other
// lengths are std::invalid_argument).
// With `silhouette` (single scans) the silhouette estimate is made too and preferred when its scan
// lines agree (the band circle and the cylinder are then not fitted unless options.fit_all);
// otherwise the better of circle and cylinder by quality. With `view_origin` (where every point
// was seen from: the sensor of a single scan) the band circle is fitted under range noise
// (fitCircleRays).
StemDiameter estimateDiameter(const Eigen::Ref<const Points3> &points,
                              const Eigen::Ref<const Points3> &normals, double base_z,
                              const Eigen::Vector3d &up, const DiameterConfig &options,
                              const SilhouetteView *silhouette = nullptr,
                              const Eigen::Vector3d *view_origin = nullptr);

// Where a stem's breast height (1.3 m above its base) came from.
enum class BreastHeightSource {
    Ground = 0,       // local ground under the stem
    LowestPoint = 1,  // no ground: the stem's lowest point is taken as its base
    Slice = 2,        // no ground and the stem is shorter than the band: its middle height
    Explicit = 3,     // given by the user (PerceptionConfig::breast_height_z)
};

struct Stem {
    int id = 0;
    Points3 points;
    Points3 normals;
    ClusterShape shape;
    double base_z = kNaN;       // local ground height under the stem
    bool ground_found = false;  // false: base_z is the stem's lowest point
    BreastHeightSource breast_source = BreastHeightSource::Ground;
    Eigen::Vector3d breast = Eigen::Vector3d::Constant(kNaN);  // centre at 1.3 m
    StemDiameter diameter;
};

// Local ground height: median z of `ground` points within `radius` (XY) of `xy`; NaN if none.
double localGroundHeight(const Eigen::Ref<const Points3> &ground, const Eigen::Vector2d &xy,
                         double radius);

// Ground points (finite x, y) sorted by x, for many localGroundHeight look-ups on one ground:
// each tests only the strip of x within its radius.
struct GroundByX {
    std::vector<Eigen::Vector3d> p;
};
GroundByX groundByX(const Eigen::Ref<const Points3> &ground);

// localGroundHeight(ground, xy, radius) on the sorted ground: the identical result.
double localGroundHeight(const GroundByX &ground, const Eigen::Vector2d &xy, double radius);

// Ground height at `xy` from a least-squares plane z = a x + b y + c through the ground points
// within `radius` (one trimming pass against bushes); NaN with fewer than 10 points.
double planeGroundHeight(const Eigen::Ref<const Points3> &ground, const Eigen::Vector2d &xy,
                         double radius);

}  // namespace forestslam::perception
