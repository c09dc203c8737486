#include "forestslam/registration/point_to_plane_icp.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "forestslam/common/kdtree.hpp"
#include "forestslam/common/scatter.hpp"

namespace forestslam::registration {
namespace {
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
}  // namespace

// Normals are computed on first use: ICP touches only the map points near its source (about a
// third of a local map between two keyframes), and a normal depends on the point's
// neighbourhood alone, so results are the same as computing all of them up front.
struct PlaneTarget::Impl {
    enum : unsigned char { kPending = 0, kWriting = 1, kDone = 2 };
    Points3 points;
    Points3 normals;  // rows valid once state[row] == kDone
    KdTree3 all;
    int k = 3;
    std::vector<std::atomic<unsigned char>> state;

    // PCA normal of row i's k nearest (NaN when the neighbourhood is not planar enough).
    Eigen::Vector3d computeNormal(Eigen::Index i) const {
        thread_local std::vector<std::pair<double, int>> nn;
        const double inf = std::numeric_limits<double>::infinity();
        const Eigen::Vector3d nan = Eigen::Vector3d::Constant(kNaN);
        const int found = all.knn(points.row(i).transpose(), k, inf, nn);
        if (found < 3) return nan;
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(neighbourScatter(points, nn));
        const Eigen::Vector3d ev = eig.eigenvalues();
        // Reject lines (a single scan ring) and blobs: the middle spread must be a fair share of
        // the largest and well above the normal direction's.
        if (!(ev(1) > 3.0 * ev(0)) || !(ev(1) > 0.02 * ev(2)) || !(ev(1) > 1e-8)) return nan;
        return eig.eigenvectors().col(0);
    }

    // Thread-safe: the first caller to claim a row stores it; a concurrent caller that finds it
    // being written uses its own (identical) result without storing it.
    Eigen::Vector3d normal(Eigen::Index i) {
        std::atomic<unsigned char> &s = state[static_cast<size_t>(i)];
        if (s.load(std::memory_order_acquire) == kDone) return normals.row(i).transpose();
        const Eigen::Vector3d n = computeNormal(i);
        unsigned char expected = kPending;
        if (s.compare_exchange_strong(expected, kWriting, std::memory_order_acq_rel)) {
            normals.row(i) = n.transpose();
            s.store(kDone, std::memory_order_release);
        }
        return n;
    }
};

PlaneTarget::PlaneTarget(const Eigen::Ref<const Points3> &points_in, int normal_k)
    : impl_(std::make_unique<Impl>()) {
    impl_->points = finiteRows(points_in);
    const Eigen::Index m = impl_->points.rows();
    impl_->normals = Points3::Constant(m, 3, kNaN);
    impl_->state = std::vector<std::atomic<unsigned char>>(static_cast<size_t>(m));
    const unsigned char initial = m < 3 ? Impl::kDone : Impl::kPending;  // < 3: no normals
    for (Eigen::Index i = 0; i < m; ++i) impl_->state[static_cast<size_t>(i)] = initial;
    if (m == 0) return;
    std::vector<int> rows(static_cast<size_t>(m));
    std::iota(rows.begin(), rows.end(), 0);
    impl_->all.build(impl_->points, rows);
    impl_->k = std::max(3, std::min<int>(normal_k, static_cast<int>(m)));
}

PlaneTarget::~PlaneTarget() = default;
PlaneTarget::PlaneTarget(PlaneTarget &&) noexcept = default;
PlaneTarget &PlaneTarget::operator=(PlaneTarget &&) noexcept = default;

const Points3 &PlaneTarget::points() const { return impl_->points; }
const Points3 &PlaneTarget::normals() const {
    for (Eigen::Index i = 0; i < impl_->points.rows(); ++i) {
        impl_->normal(i);
        // A row another thread is storing at this moment is complete only once it says so.
        while (impl_->state[static_cast<size_t>(i)].load(std::memory_order_acquire) != Impl::kDone)
            std::this_thread::yield();
    }
    return impl_->normals;
}

Eigen::Vector3d PlaneTarget::normal(int row) const {
    if (row < 0 || row >= impl_->points.rows())
        throw std::out_of_range("PlaneTarget::normal: row " + std::to_string(row) +
                                " outside the target's " + std::to_string(impl_->points.rows()) +
                                " points");
    return impl_->normal(row);
}
Eigen::Index PlaneTarget::size() const { return impl_->points.rows(); }

int PlaneTarget::nearest(const Eigen::Vector3d &query, double &squared_distance) const {
    return impl_->all.nearest(query, std::numeric_limits<double>::infinity(), squared_distance);
}

int PlaneTarget::nearest(const Eigen::Vector3d &query, double max_distance_m,
                         double &squared_distance) const {
    return impl_->all.nearest(query, max_distance_m * max_distance_m, squared_distance);
}

double pointToPlaneResidual(const Pose3 &T, const Eigen::Vector3d &p, const Eigen::Vector3d &q,
                            const Eigen::Vector3d &n, Eigen::Matrix<double, 1, 6> *jacobian) {
    const Eigen::Vector3d pw = T * p;
    if (jacobian) {
        jacobian->head<3>() = n.transpose();
        jacobian->tail<3>() = pw.cross(n).transpose();
    }
    return n.dot(pw - q);
}

namespace {

// Rotation vector of R (log map).
Eigen::Vector3d logSO3(const Eigen::Matrix3d &R) {
    const Eigen::AngleAxisd aa(R);
    return aa.angle() * aa.axis();
}

// Huber-weighted Gauss-Newton system of the correspondences within max_d of the pose T.
struct NormalEquations {
    Matrix6d H = Matrix6d::Zero();
    Vector6d b = Vector6d::Zero();
    int used = 0;
    double sse = 0.0;
};

// Search radius for source point p's nearest target point: its previous nearest `last` (-1:
// none) is at most this far, so the search can be bounded there and still finds the same point
// (the k-d tree keeps the last of equally near points in a fixed visiting order, and every
// subtree that can hold one of them is still visited). Slightly enlarged against rounding.
double warmRadius(const Points3 &tp, int last, const Eigen::Vector3d &q, double max_d) {
    if (last < 0) return max_d;
    const double dx = q.x() - tp(last, 0), dy = q.y() - tp(last, 1), dz = q.z() - tp(last, 2);
    const double d2 = dx * dx + dy * dy + dz * dz;
    return std::min(max_d, std::sqrt(d2) * (1.0 + 1e-9) + 1e-12);
}

// `last` holds each source point's nearest target point of the previous iteration (-1: none)
// and is updated; the nearest points found are those of an unbounded search.
// Every stride-th source point only.
NormalEquations linearise(const PlaneTarget &target, const Points3 &source, const Pose3 &T,
                          double max_d, const IcpConfig &config, std::vector<int> &last,
                          int stride) {
    const Points3 &tp = target.points();
    const double max_d2 = max_d * max_d;
    NormalEquations eq;
    Eigen::Matrix<double, 1, 6> J;
    for (Eigen::Index i = 0; i < source.rows(); i += stride) {
        const Eigen::Vector3d p = source.row(i).transpose();
        const Eigen::Vector3d q = T * p;
        double d2 = 0.0;
        int &j = last[static_cast<size_t>(i)];
        const int found = target.nearest(q, warmRadius(tp, j, q, max_d), d2);
        if (found >= 0) j = found;  // else the previous one stays the best bound known
        if (found < 0 || d2 > max_d2) continue;
        const Eigen::Vector3d n = target.normal(found);
        if (std::isnan(n.x())) continue;
        const double r = pointToPlaneResidual(T, p, tp.row(found).transpose(), n, &J);
        const double a = std::abs(r);
        const double w = a <= config.huber_m ? 1.0 : config.huber_m / a;
        eq.H.noalias() += w * J.transpose() * J;
        eq.b.noalias() += w * r * J.transpose();
        eq.sse += w * r * r;
        ++eq.used;
    }
    return eq;
}

// The pose increment (left perturbation), the prior towards T_prior included.
Vector6d solveStep(const NormalEquations &eq, const Pose3 &T, const Matrix6d &prior_information,
                   const Pose3 &T_prior) {
    Matrix6d A = eq.H;
    Vector6d g = eq.b;
    if (!prior_information.isZero()) {
        const Pose3 E = T * T_prior.inverse();
        Vector6d e;
        e.head<3>() = E.translation();
        e.tail<3>() = logSO3(E.linear());
        A += prior_information;
        g += prior_information * e;
    }
    return A.ldlt().solve(-g);
}

// Per-iteration factor that brings the correspondence distance from max_d down to the final
// one in shrink_iterations (at most half of the iterations).
double shrinkFactor(const IcpConfig &config, double max_d) {
    if (config.max_iterations <= 1) return 1.0;
    const int steps = std::max(1, std::min(config.shrink_iterations, config.max_iterations / 2));
    return std::pow(config.final_correspondence_m / max_d, 1.0 / steps);
}

// Degeneracy: eigenvalues of the per-correspondence information with rotations in metres.
bool isDegenerate(const NormalEquations &eq, const IcpConfig &config) {
    Matrix6d S = Matrix6d::Identity();
    S.bottomRightCorner<3, 3>() *= 1.0 / config.degeneracy_length_m;
    const Matrix6d Hn = S * eq.H * S / eq.used;
    Eigen::SelfAdjointEigenSolver<Matrix6d> eig(Hn);
    return !(eig.eigenvalues()(0) > config.degeneracy_threshold);
}

// (H + prior)^-1 with H scaled by the residual variance; directions without information get
// kUnobservedVariance.
Matrix6d covarianceOf(const NormalEquations &eq, const Matrix6d &prior_information) {
    const double sigma2 = eq.sse / std::max(1, eq.used - 6);
    const Matrix6d info = eq.H / std::max(sigma2, 1e-8) + prior_information;
    Eigen::SelfAdjointEigenSolver<Matrix6d> eig(info);
    if (eig.eigenvalues()(0) > 1e-12) return info.inverse();
    Matrix6d cov = Matrix6d::Zero();
    for (int k = 0; k < 6; ++k) {
        const double l = eig.eigenvalues()(k);
        const double v = l > 1e-12 ? 1.0 / l : kUnobservedVariance;
        cov += v * eig.eigenvectors().col(k) * eig.eigenvectors().col(k).transpose();
    }
    return cov;
}

}  // namespace

RegistrationResult icpPointToPlane(const PlaneTarget &target,
                                   const Eigen::Ref<const Points3> &source_in, const Pose3 &T_init,
                                   const IcpConfig &config, const Matrix6d &prior_information,
                                   const Pose3 &T_prior) {
    if (!T_init.matrix().allFinite() || !T_prior.matrix().allFinite() ||
        !prior_information.allFinite())
        throw std::invalid_argument(
            "icpPointToPlane: T_init, T_prior and prior_information "
            "must be finite");
    RegistrationResult result;
    result.T_target_source = T_init;
    result.covariance = Matrix6d::Identity() * kUnobservedVariance;
    const Points3 source = finiteRows(source_in);
    if (target.size() < 3 || source.rows() == 0) return result;

    Pose3 T = T_init;
    double max_d = std::max(config.max_correspondence_m, config.final_correspondence_m);
    const double shrink = shrinkFactor(config, max_d);
    NormalEquations eq;
    std::vector<int> last(static_cast<size_t>(source.rows()), -1);
    bool converged = false;
    int it = 0;
    for (; it < config.max_iterations; ++it) {
        const bool coarse = max_d > config.final_correspondence_m + 1e-9;
        const int stride = coarse ? std::max(1, config.coarse_stride) : 1;
        eq = linearise(target, source, T, max_d, config, last, stride);
        if (eq.used < config.min_correspondences) {
            if (stride == 1) break;
            eq = linearise(target, source, T, max_d, config, last, 1);  // too few: all points
            if (eq.used < config.min_correspondences) break;
        }
        const Vector6d delta = solveStep(eq, T, prior_information, T_prior);
        if (!delta.allFinite()) break;
        T = expSE3(delta) * T;
        max_d = std::max(config.final_correspondence_m, max_d * shrink);
        if (stride == 1 && delta.head<3>().norm() < config.translation_tolerance_m &&
            delta.tail<3>().norm() < config.rotation_tolerance_rad &&
            max_d <= config.final_correspondence_m + 1e-9) {
            converged = true;
            ++it;
            break;
        }
    }
    result.iterations = it;
    result.inliers = eq.used;
    result.T_target_source = T;
    if (eq.used < config.min_correspondences) return result;
    result.converged = converged;
    result.rmse = std::sqrt(eq.sse / eq.used);
    result.degenerate = isDegenerate(eq, config);
    result.covariance = covarianceOf(eq, prior_information);
    return result;
}

}  // namespace forestslam::registration
