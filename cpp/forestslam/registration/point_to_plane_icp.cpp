#include "forestslam/registration/point_to_plane_icp.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numeric>
#include <vector>

namespace forestslam {
namespace {

// Static 3-D k-d tree with leaf buckets over a subset of rows of a point matrix; exact nearest
// and k-nearest queries bounded by a maximum distance (ICP gates its correspondences, so most of
// the tree is pruned). Points are copied in tree order for cache-friendly leaves. Written for
// this use instead of PCL's KdTreeFLANN, whose per-query overhead dominated the ICP.
class KdTree3 {
  public:
    void build(const Points3 &points, std::vector<int> rows) {
        ids_ = std::move(rows);
        nodes_.clear();
        pts_.clear();
        if (ids_.empty()) return;
        nodes_.reserve(2 * ids_.size() / kLeaf + 2);
        buildNode(points, 0, static_cast<int>(ids_.size()));
        pts_.resize(ids_.size());
        for (size_t k = 0; k < ids_.size(); ++k)
            pts_[k] = {points(ids_[k], 0), points(ids_[k], 1), points(ids_[k], 2)};
    }

    bool empty() const { return ids_.empty(); }

    // Row of the nearest point within sqrt(max_d2) of q (-1 if none) and its squared distance.
    int nearest(const Eigen::Vector3d &q, double max_d2, double &d2) const {
        if (ids_.empty()) return -1;
        const std::array<double, 3> qa{q.x(), q.y(), q.z()};
        double best = max_d2;
        int best_k = -1;
        nearestIn(0, qa, best, best_k);
        if (best_k < 0) return -1;
        d2 = best;
        return ids_[static_cast<size_t>(best_k)];
    }

    // Up to k nearest rows (ascending distance) within sqrt(max_d2); returns how many.
    int knn(const Eigen::Vector3d &q, int k, double max_d2, std::vector<int> &rows,
            std::vector<double> &d2) const {
        rows.clear();
        d2.clear();
        if (ids_.empty() || k <= 0) return 0;
        const std::array<double, 3> qa{q.x(), q.y(), q.z()};
        Heap h{std::vector<std::pair<double, int>>(), static_cast<size_t>(k), max_d2};
        h.items.reserve(static_cast<size_t>(k) + 1);
        knnIn(0, qa, h);
        for (const auto &[dd, kk] : h.items) {
            rows.push_back(ids_[static_cast<size_t>(kk)]);
            d2.push_back(dd);
        }
        return static_cast<int>(rows.size());
    }

  private:
    static constexpr int kLeaf = 8;
    struct Node {
        double split = 0;
        int axis = -1;  // -1: leaf over [begin, end)
        int begin = 0, end = 0;
        int left = -1, right = -1;
    };
    // Sorted (ascending) candidates; `bound` is the current k-th distance (or the gate).
    struct Heap {
        std::vector<std::pair<double, int>> items;
        size_t k;
        double bound;
        void push(double dd, int idx) {
            auto it = std::upper_bound(items.begin(), items.end(), std::make_pair(dd, idx));
            items.insert(it, {dd, idx});
            if (items.size() > k) items.pop_back();
            if (items.size() == k) bound = std::min(bound, items.back().first);
        }
    };

    int buildNode(const Points3 &points, int begin, int end) {
        const int id = static_cast<int>(nodes_.size());
        nodes_.emplace_back();
        nodes_[static_cast<size_t>(id)].begin = begin;
        nodes_[static_cast<size_t>(id)].end = end;
        if (end - begin <= kLeaf) return id;
        Eigen::Array3d lo = Eigen::Array3d::Constant(std::numeric_limits<double>::max());
        Eigen::Array3d hi = -lo;
        for (int k = begin; k < end; ++k) {
            const Eigen::Array3d p = points.row(ids_[static_cast<size_t>(k)]).transpose().array();
            lo = lo.min(p);
            hi = hi.max(p);
        }
        int axis = 0;
        (hi - lo).maxCoeff(&axis);
        const int mid = begin + (end - begin) / 2;
        std::nth_element(ids_.begin() + begin, ids_.begin() + mid, ids_.begin() + end,
                         [&](int a, int b) { return points(a, axis) < points(b, axis); });
        const double split = points(ids_[static_cast<size_t>(mid)], axis);
        const int left = buildNode(points, begin, mid);
        const int right = buildNode(points, mid, end);
        Node &n = nodes_[static_cast<size_t>(id)];
        n.axis = axis;
        n.split = split;
        n.left = left;
        n.right = right;
        return id;
    }

    static double dist2(const std::array<double, 3> &a, const std::array<double, 3> &b) {
        const double dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
        return dx * dx + dy * dy + dz * dz;
    }

    void nearestIn(int id, const std::array<double, 3> &q, double &best, int &best_k) const {
        const Node &n = nodes_[static_cast<size_t>(id)];
        if (n.axis < 0) {
            for (int k = n.begin; k < n.end; ++k) {
                const double dd = dist2(pts_[static_cast<size_t>(k)], q);
                if (dd <= best) best = dd, best_k = k;
            }
            return;
        }
        const double diff = q[static_cast<size_t>(n.axis)] - n.split;
        nearestIn(diff < 0 ? n.left : n.right, q, best, best_k);
        if (diff * diff <= best) nearestIn(diff < 0 ? n.right : n.left, q, best, best_k);
    }

    void knnIn(int id, const std::array<double, 3> &q, Heap &h) const {
        const Node &n = nodes_[static_cast<size_t>(id)];
        if (n.axis < 0) {
            for (int k = n.begin; k < n.end; ++k) {
                const double dd = dist2(pts_[static_cast<size_t>(k)], q);
                if (dd <= h.bound) h.push(dd, k);
            }
            return;
        }
        const double diff = q[static_cast<size_t>(n.axis)] - n.split;
        knnIn(diff < 0 ? n.left : n.right, q, h);
        if (diff * diff <= h.bound) knnIn(diff < 0 ? n.right : n.left, q, h);
    }

    std::vector<int> ids_;
    std::vector<std::array<double, 3>> pts_;
    std::vector<Node> nodes_;
};

}  // namespace

struct PlaneTarget::Impl {
    Points3 points;
    Points3 normals;
    KdTree3 all;
};

PlaneTarget::PlaneTarget(const Eigen::Ref<const Points3> &points_in, int normal_k)
    : impl_(std::make_unique<Impl>()) {
    impl_->points = finiteRows(points_in);
    const Eigen::Index m = impl_->points.rows();
    impl_->normals = Points3::Constant(m, 3, std::numeric_limits<double>::quiet_NaN());
    if (m == 0) return;
    std::vector<int> rows(static_cast<size_t>(m));
    std::iota(rows.begin(), rows.end(), 0);
    impl_->all.build(impl_->points, rows);
    if (m < 3) return;
    const int k = std::max(3, std::min<int>(normal_k, static_cast<int>(m)));
    std::vector<int> idx;
    std::vector<double> d2;
    const double inf = std::numeric_limits<double>::infinity();
    for (Eigen::Index i = 0; i < m; ++i) {
        const int found = impl_->all.knn(impl_->points.row(i).transpose(), k, inf, idx, d2);
        if (found < 3) continue;
        Eigen::Vector3d mean = Eigen::Vector3d::Zero();
        for (int j = 0; j < found; ++j) mean += impl_->points.row(idx[j]).transpose();
        mean /= found;
        Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
        for (int j = 0; j < found; ++j) {
            const Eigen::Vector3d d = impl_->points.row(idx[j]).transpose() - mean;
            cov += d * d.transpose();
        }
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
        const Eigen::Vector3d ev = eig.eigenvalues();
        // Reject lines (a single scan ring) and blobs: the middle spread must be a fair share of
        // the largest and well above the normal direction's.
        if (!(ev(1) > 3.0 * ev(0)) || !(ev(1) > 0.02 * ev(2)) || !(ev(1) > 1e-8)) continue;
        impl_->normals.row(i) = eig.eigenvectors().col(0).transpose();
    }
}

PlaneTarget::~PlaneTarget() = default;
PlaneTarget::PlaneTarget(PlaneTarget &&) noexcept = default;
PlaneTarget &PlaneTarget::operator=(PlaneTarget &&) noexcept = default;

const Points3 &PlaneTarget::points() const { return impl_->points; }
const Points3 &PlaneTarget::normals() const { return impl_->normals; }
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

}  // namespace

RegistrationResult icpPointToPlane(const PlaneTarget &target,
                                   const Eigen::Ref<const Points3> &source_in, const Pose3 &T_init,
                                   const IcpConfig &config, const Matrix6d &prior_information,
                                   const Pose3 &T_prior) {
    RegistrationResult result;
    result.T_target_source = T_init.matrix();
    result.covariance = Matrix6d::Identity() * kUnobservedVariance;
    const Points3 source = finiteRows(source_in);
    if (target.size() < 3 || source.rows() == 0) return result;

    const Points3 &tp = target.points();
    const Points3 &tn = target.normals();
    Pose3 T = T_init;
    double max_d = std::max(config.max_correspondence_m, config.final_correspondence_m);
    const double shrink = config.max_iterations > 1
                              ? std::pow(config.final_correspondence_m / max_d,
                                         1.0 / std::max(1, std::min(config.shrink_iterations, config.max_iterations / 2)))
                              : 1.0;
    Matrix6d H = Matrix6d::Zero();
    int used = 0;
    double sse = 0.0;
    bool converged = false;
    int it = 0;
    for (; it < config.max_iterations; ++it) {
        H.setZero();
        Vector6d b = Vector6d::Zero();
        used = 0;
        sse = 0.0;
        const double max_d2 = max_d * max_d;
        Eigen::Matrix<double, 1, 6> J;
        for (Eigen::Index i = 0; i < source.rows(); ++i) {
            const Eigen::Vector3d p = source.row(i).transpose();
            double d2 = 0.0;
            const int j = target.nearest(T * p, max_d, d2);
            if (j < 0 || d2 > max_d2 || std::isnan(tn(j, 0))) continue;
            const double r = pointToPlaneResidual(T, p, tp.row(j).transpose(), tn.row(j).transpose(), &J);
            const double a = std::abs(r);
            const double w = a <= config.huber_m ? 1.0 : config.huber_m / a;
            H.noalias() += w * J.transpose() * J;
            b.noalias() += w * r * J.transpose();
            sse += w * r * r;
            ++used;
        }
        if (used < config.min_correspondences) break;
        Matrix6d A = H;
        Vector6d g = b;
        if (!prior_information.isZero()) {
            const Pose3 E = T * T_prior.inverse();
            Vector6d e;
            e.head<3>() = E.translation();
            e.tail<3>() = logSO3(E.linear());
            A += prior_information;
            g += prior_information * e;
        }
        const Vector6d delta = A.ldlt().solve(-g);
        if (!delta.allFinite()) break;
        T = expSE3(delta) * T;
        max_d = std::max(config.final_correspondence_m, max_d * shrink);
        if (delta.head<3>().norm() < config.translation_tolerance_m &&
            delta.tail<3>().norm() < config.rotation_tolerance_rad && max_d <= config.final_correspondence_m + 1e-9) {
            converged = true;
            ++it;
            break;
        }
    }
    result.iterations = it;
    result.inliers = used;
    result.T_target_source = T.matrix();
    if (used < config.min_correspondences) return result;
    result.converged = converged;
    result.rmse = std::sqrt(sse / used);

    // Degeneracy: eigenvalues of the per-correspondence information with rotations in metres.
    Matrix6d S = Matrix6d::Identity();
    S.bottomRightCorner<3, 3>() *= 1.0 / config.degeneracy_length_m;
    const Matrix6d Hn = S * H * S / used;
    Eigen::SelfAdjointEigenSolver<Matrix6d> eig(Hn);
    result.degenerate = !(eig.eigenvalues()(0) > config.degeneracy_threshold);
    // Covariance: (H + prior)^-1 scaled by the residual variance.
    const double sigma2 = sse / std::max(1, used - 6);
    Matrix6d info = H / std::max(sigma2, 1e-8) + prior_information;
    Eigen::SelfAdjointEigenSolver<Matrix6d> eig_info(info);
    if (eig_info.eigenvalues()(0) > 1e-12) {
        result.covariance = info.inverse();
    } else {
        // Invert on the observed subspace only; unobserved directions get kUnobservedVariance.
        Matrix6d cov = Matrix6d::Zero();
        for (int k = 0; k < 6; ++k) {
            const double l = eig_info.eigenvalues()(k);
            const double v = l > 1e-12 ? 1.0 / l : kUnobservedVariance;
            cov += v * eig_info.eigenvectors().col(k) * eig_info.eigenvectors().col(k).transpose();
        }
        result.covariance = cov;
    }
    return result;
}

}  // namespace forestslam
