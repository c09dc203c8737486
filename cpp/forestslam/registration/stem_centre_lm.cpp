#include "forestslam/registration/stem_centre_lm.hpp"

#include <ceres/ceres.h>
#include <pcl/kdtree/kdtree_flann.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <unordered_map>
#include <vector>

#include "forestslam/common/pcl_adapter.hpp"

namespace forestslam {

namespace {
constexpr double kCell = 0.2;  // hash cell of the target for the virtual-feature search
std::int64_t cellIndex(double v) { return static_cast<std::int64_t>(std::floor(v / kCell)); }
std::int64_t cellKey(std::int64_t ix, std::int64_t iy, std::int64_t iz) {
    return ((ix & 0x1FFFFF) << 42) | ((iy & 0x1FFFFF) << 21) | (iz & 0x1FFFFF);
}
}  // namespace

struct StemCentreTarget::Impl {
    Points3 points;
    pcl::PointCloud<pcl::PointXYZ>::Ptr cloud;
    pcl::KdTreeFLANN<pcl::PointXYZ> tree;
    std::unordered_map<std::int64_t, std::vector<int>> cells;
};

StemCentreTarget::StemCentreTarget(const Eigen::Ref<const Points3> &points)
    : impl_(std::make_unique<Impl>()) {
    impl_->points = finiteRows(points);
    impl_->cloud = detail::toPcl(impl_->points);
    if (!impl_->cloud->empty()) impl_->tree.setInputCloud(impl_->cloud);
    for (Eigen::Index i = 0; i < impl_->points.rows(); ++i) {
        const auto &p = impl_->points.row(i);
        impl_->cells[cellKey(cellIndex(p(0)), cellIndex(p(1)), cellIndex(p(2)))].push_back(
            static_cast<int>(i));
    }
}

StemCentreTarget::~StemCentreTarget() = default;
Eigen::Index StemCentreTarget::size() const { return impl_->points.rows(); }
const Points3 &StemCentreTarget::points() const { return impl_->points; }

namespace {

struct VirtualPair {
    Eigen::Vector3d centre, target;
    double radius;
    double weight;  // virtual_weight shared by the pairs of one centre
};
struct PlanePair {
    Eigen::Vector3d source, origin, normal;
};

// All pairs of one correspondence round in one residual block with analytic Jacobians. The
// parameters are a left perturbation [dt (3), dw (3)] of the round's starting pose T0:
// q = exp(dw) (R0 s + t0) + dt. Pair i has the raw residual r_i = d - r (virtual: d the
// horizontal distance to the paired target point) or the point-to-plane distance (real) and
// contributes w_i * rho(r_i) with rho the Cauchy loss of scale c: the block returns
// f_i = sqrt(w_i) sign(r_i) sqrt(rho(r_i)), rho(r) = c^2 log(1 + r^2 / c^2), so that the sum of
// squares is exactly the robust cost (one block instead of one per pair: the per-block
// overhead dominated). Jacobian of q w.r.t. dw: -[q]x (exact at dw = 0, first order within
// the round's small step).
class PairsCost : public ceres::CostFunction {
  public:
    PairsCost(const std::vector<VirtualPair> &v, const std::vector<PlanePair> &p,
              const Eigen::Matrix4d &T0, double scale)
        : v_(v), p_(p), c_(scale) {
        R0_ = T0.block<3, 3>(0, 0);
        t0_ = T0.block<3, 1>(0, 3);
        set_num_residuals(static_cast<int>(v.size() + p.size()));
        mutable_parameter_block_sizes()->push_back(6);
    }

    bool Evaluate(double const *const *parameters, double *residuals,
                  double **jacobians) const override {
        const double *d = parameters[0];
        const Eigen::Vector3d dt(d[0], d[1], d[2]), dw(d[3], d[4], d[5]);
        const double angle = dw.norm();
        const Eigen::Matrix3d dR = angle > 0
                                       ? Eigen::AngleAxisd(angle, dw / angle).toRotationMatrix()
                                       : Eigen::Matrix3d::Identity();
        const Eigen::Matrix3d R = dR * R0_;
        const Eigen::Vector3d t = dR * t0_ + dt;
        double *J = (jacobians != nullptr) ? jacobians[0] : nullptr;
        std::size_t i = 0;
        for (const auto &v : v_) {
            const Eigen::Vector3d q = R * v.centre + t;
            const double dx = q.x() - v.target.x(), dy = q.y() - v.target.y();
            const double dn = std::sqrt(dx * dx + dy * dy + 1e-12);
            double f, df;
            robust(dn - v.radius, f, df);
            const double w = std::sqrt(v.weight);
            residuals[i] = w * f;
            if (J != nullptr) {
                const Eigen::Vector3d u(dx / dn, dy / dn, 0.0);
                writeRow(J + 6 * i, u, q, w * df);
            }
            ++i;
        }
        for (const auto &p : p_) {
            const Eigen::Vector3d q = R * p.source + t;
            double f, df;
            robust(p.normal.dot(q - p.origin), f, df);
            residuals[i] = f;
            if (J != nullptr) writeRow(J + 6 * i, p.normal, q, df);
            ++i;
        }
        return true;
    }

  private:
    // f = sign(r) sqrt(rho(r)) and df/dr = r / ((1 + r^2/c^2) f) (-> 1 at r = 0).
    void robust(double r, double &f, double &df) const {
        const double u = r / c_;
        if (std::abs(u) < 1e-6) {
            f = r;
            df = 1.0;
            return;
        }
        f = std::copysign(c_ * std::sqrt(std::log1p(u * u)), r);
        df = r / ((1.0 + u * u) * f);
    }

    // d r / d [dt, dw] = [u, q x u] (u the residual direction), scaled by w.
    static void writeRow(double *row, const Eigen::Vector3d &u, const Eigen::Vector3d &q,
                         double w) {
        const Eigen::Vector3d qu = q.cross(u);
        for (int k = 0; k < 3; ++k) {
            row[k] = w * u[k];
            row[3 + k] = w * qu[k];
        }
    }

    const std::vector<VirtualPair> &v_;
    const std::vector<PlanePair> &p_;
    double c_;
    Eigen::Matrix3d R0_;
    Eigen::Vector3d t0_;
};

// Target points that can pair with each virtual feature, gathered with a slack around where
// the centre was: reused while the moved centre stays within the slack (exact, as a pair needs
// |d - r| < gate <= virtual_max_gate_m and |dz| <= virtual_window_m), so the hash cells are
// scanned about once per registration instead of once per round.
struct VirtualCandidates {
    static constexpr double kSlack = 0.3;
    std::vector<Eigen::Vector3d> at;        // transformed centre when gathered
    std::vector<std::vector<int>> members;  // target point indices
    std::vector<char> valid;

    void gather(const StemCentreTarget::Impl &target, std::size_t i, const Eigen::Vector3d &q,
                double radius, const StemCentreLmConfig &cfg) {
        if (at.size() <= i) {
            at.resize(i + 1);
            members.resize(i + 1);
            valid.resize(i + 1, 0);
        }
        auto &out = members[i];
        out.clear();
        const double reach = radius + cfg.virtual_max_gate_m + kSlack;
        const double window = cfg.virtual_window_m + kSlack;
        for (auto ix = cellIndex(q.x() - reach); ix <= cellIndex(q.x() + reach); ++ix) {
            for (auto iy = cellIndex(q.y() - reach); iy <= cellIndex(q.y() + reach); ++iy) {
                for (auto iz = cellIndex(q.z() - window); iz <= cellIndex(q.z() + window); ++iz) {
                    const auto it = target.cells.find(cellKey(ix, iy, iz));
                    if (it == target.cells.end()) continue;
                    for (int j : it->second) {
                        const auto &p = target.points.row(j);
                        if (std::abs(p(2) - q.z()) > window) continue;
                        if (std::hypot(p(0) - q.x(), p(1) - q.y()) > reach) continue;
                        out.push_back(j);
                    }
                }
            }
        }
        at[i] = q;
        valid[i] = 1;
    }

    const std::vector<int> &near(const StemCentreTarget::Impl &target, std::size_t i,
                                 const Eigen::Vector3d &q, double radius,
                                 const StemCentreLmConfig &cfg) {
        if (i >= valid.size() || !valid[i] || std::abs(q.z() - at[i].z()) > kSlack ||
            std::hypot(q.x() - at[i].x(), q.y() - at[i].y()) > kSlack) {
            gather(target, i, q, radius, cfg);
        }
        return members[i];
    }
};

void findPairs(const StemCentreTarget::Impl &target, const Points3 &centres,
               const Eigen::VectorXd &radii, const Points3 &real, const Eigen::Matrix4d &T,
               const StemCentreLmConfig &cfg, VirtualCandidates &candidates,
               std::vector<VirtualPair> &vpairs, std::vector<PlanePair> &ppairs) {
    vpairs.clear();
    ppairs.clear();
    const Eigen::Matrix3d R = T.block<3, 3>(0, 0);
    const Eigen::Vector3d t = T.block<3, 1>(0, 3);
    std::vector<int> idx;
    std::vector<float> d2;
    const int sectors = std::max(1, cfg.virtual_sectors);
    const double gate = std::min(cfg.virtual_gate_m, cfg.virtual_max_gate_m);
    std::vector<int> best(static_cast<std::size_t>(sectors));
    std::vector<double> best_err(static_cast<std::size_t>(sectors));
    for (Eigen::Index i = 0; i < centres.rows(); ++i) {
        const Eigen::Vector3d c = centres.row(i).transpose();
        const Eigen::Vector3d q = R * c + t;
        const double r = radii[i];
        std::fill(best.begin(), best.end(), -1);
        std::fill(best_err.begin(), best_err.end(), std::numeric_limits<double>::infinity());
        for (int j : candidates.near(target, static_cast<std::size_t>(i), q, r, cfg)) {
            const auto &p = target.points.row(j);
            if (std::abs(p(2) - q.z()) > cfg.virtual_window_m) continue;
            const double dx = p(0) - q.x(), dy = p(1) - q.y();
            const double err = std::abs(std::sqrt(dx * dx + dy * dy) - r);
            if (err >= gate) continue;
            auto sector = static_cast<int>((std::atan2(dy, dx) + M_PI) / (2 * M_PI) * sectors);
            sector = std::min(std::max(sector, 0), sectors - 1);
            if (err < best_err[sector]) {
                best_err[sector] = err;
                best[sector] = j;
            }
        }
        const auto found =
            static_cast<int>(std::count_if(best.begin(), best.end(), [](int j) { return j >= 0; }));
        for (int j : best) {
            if (j >= 0) {
                vpairs.push_back(
                    {c, target.points.row(j).transpose(), r, cfg.virtual_weight / found});
            }
        }
    }
    constexpr int kPlaneCandidates = 10;
    for (Eigen::Index i = 0; i < real.rows(); ++i) {
        const Eigen::Vector3d s = real.row(i).transpose();
        const Eigen::Vector3d q = R * s + t;
        pcl::PointXYZ query(static_cast<float>(q.x()), static_cast<float>(q.y()),
                            static_cast<float>(q.z()));
        if (target.tree.nearestKSearch(query, kPlaneCandidates, idx, d2) < 3) continue;
        if (std::sqrt(d2[0]) > cfg.real_gate_m) continue;
        const Eigen::Vector3d p0 = target.points.row(idx[0]).transpose();
        const Eigen::Vector3d p1 = target.points.row(idx[1]).transpose();
        // Third point: the nearest that makes a non-degenerate triangle with the first two.
        for (std::size_t k = 2; k < idx.size(); ++k) {
            const Eigen::Vector3d p2 = target.points.row(idx[k]).transpose();
            const Eigen::Vector3d cross = (p1 - p0).cross(p2 - p0);
            const double longest = std::max(
                {(p1 - p0).squaredNorm(), (p2 - p0).squaredNorm(), (p2 - p1).squaredNorm()});
            if (longest <= 0.0 || cross.norm() / longest < cfg.min_triangle_ratio) continue;
            const Eigen::Vector3d n = cross.normalized();
            if (std::abs(n.dot(q - p0)) <= cfg.plane_gate_m) ppairs.push_back({s, p0, n});
            break;
        }
    }
}

}  // namespace

StemCentreLmResult registerStemCentreLm(const StemCentreTarget &target,
                                        const Eigen::Ref<const Points3> &virtual_centres,
                                        const Eigen::Ref<const Eigen::VectorXd> &radii,
                                        const Eigen::Ref<const Points3> &real_points,
                                        const Eigen::Matrix4d &T_initial,
                                        const StemCentreLmConfig &config) {
    StemCentreLmResult result;
    result.T_target_source = T_initial;
    if (target.size() < 3 || !T_initial.allFinite()) return result;

    // Keep only finite features (and centres with a usable radius).
    Points3 centres(0, 3);
    Eigen::VectorXd rad(0);
    {
        std::vector<int> keep;
        const Eigen::Index nv = std::min(virtual_centres.rows(), radii.size());
        for (Eigen::Index i = 0; i < nv; ++i) {
            if (virtual_centres.row(i).allFinite() && std::isfinite(radii[i]) && radii[i] > 0) {
                keep.push_back(static_cast<int>(i));
            }
        }
        centres = selectRows(virtual_centres, keep);
        rad.resize(static_cast<Eigen::Index>(keep.size()));
        for (std::size_t k = 0; k < keep.size(); ++k) rad[k] = radii[keep[k]];
    }
    const Points3 real = finiteRows(real_points);

    Eigen::Matrix4d T_cur = T_initial;
    VirtualCandidates candidates;
    std::vector<VirtualPair> vpairs;
    std::vector<PlanePair> ppairs;
    for (int round = 0; round < config.max_rounds; ++round) {
        const Eigen::Matrix4d T_before = T_cur;
        const double scale =
            std::max(1.0, config.coarse_gate_factor * std::pow(config.gate_decay, round));
        StemCentreLmConfig round_cfg = config;
        round_cfg.virtual_gate_m *= scale;
        round_cfg.real_gate_m *= scale;
        round_cfg.plane_gate_m *= scale;
        round_cfg.robust_scale_m *= scale;
        findPairs(target.impl(), centres, rad, real, T_before, round_cfg, candidates, vpairs,
                  ppairs);
        result.iterations = round + 1;
        if (static_cast<int>(vpairs.size() + ppairs.size()) < config.min_inliers) break;

        double delta[6] = {0, 0, 0, 0, 0, 0};
        ceres::Problem::Options problem_options;
        ceres::Problem problem(problem_options);
        problem.AddResidualBlock(new PairsCost(vpairs, ppairs, T_before, round_cfg.robust_scale_m),
                                 nullptr, delta);
        ceres::Solver::Options options;
        options.minimizer_type = ceres::TRUST_REGION;
        options.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
        options.linear_solver_type = ceres::DENSE_QR;
        options.max_num_iterations = config.max_solver_iterations;
        options.num_threads = 1;
        options.logging_type = ceres::SILENT;
        ceres::Solver::Summary summary;
        ceres::Solve(options, &problem, &summary);

        const Eigen::Vector3d dw(delta[3], delta[4], delta[5]);
        const double angle = dw.norm();
        Eigen::Matrix4d D = Eigen::Matrix4d::Identity();
        if (angle > 0)
            D.block<3, 3>(0, 0) = Eigen::AngleAxisd(angle, dw / angle).toRotationMatrix();
        D.block<3, 1>(0, 3) = Eigen::Vector3d(delta[0], delta[1], delta[2]);
        T_cur = D * T_before;
        // The step as seen from the sensor (independent of where the target origin lies).
        const Eigen::Matrix4d step = T_before.inverse() * T_cur;
        if (scale <= 1.0 && step.block<3, 1>(0, 3).norm() < config.converged_translation_m &&
            angle < config.converged_rotation_rad) {
            result.converged = true;
            break;
        }
    }
    // Re-orthonormalise (the left updates accumulate rounding).
    Eigen::Matrix4d T = T_cur;
    T.block<3, 3>(0, 0) = Eigen::Quaterniond(Eigen::Matrix3d(T_cur.block<3, 3>(0, 0)))
                              .normalized()
                              .toRotationMatrix();
    result.T_target_source = T;

    // Statistics and covariance at the solution with renewed pairs.
    findPairs(target.impl(), centres, rad, real, T, config, candidates, vpairs, ppairs);
    result.virtual_inliers = static_cast<int>(vpairs.size());
    result.real_inliers = static_cast<int>(ppairs.size());
    result.inliers = result.virtual_inliers + result.real_inliers;
    if (result.inliers < config.min_inliers) {
        result.converged = false;
        return result;
    }
    const Eigen::Matrix3d R = T.block<3, 3>(0, 0);
    const Eigen::Vector3d t = T.block<3, 1>(0, 3);
    // Each pair: transformed point q, residual direction, residual, Cauchy IRLS weight.
    std::vector<Eigen::Vector3d> qs, dirs;
    std::vector<double> res, wts;
    auto add = [&](const Eigen::Vector3d &q, const Eigen::Vector3d &dir, double r, double w) {
        const double u = r / config.robust_scale_m;
        qs.push_back(q);
        dirs.push_back(dir);
        res.push_back(r);
        wts.push_back(w / (1.0 + u * u));
    };
    double vsum = 0.0, psum = 0.0;
    for (const auto &v : vpairs) {
        const Eigen::Vector3d q = R * v.centre + t;
        const Eigen::Vector3d d(q.x() - v.target.x(), q.y() - v.target.y(), 0.0);
        const double dn = std::max(d.norm(), 1e-9);
        const double r = dn - v.radius;
        vsum += r * r;
        add(q, d / dn, r, v.weight);
    }
    for (const auto &p : ppairs) {
        const Eigen::Vector3d q = R * p.source + t;
        const double r = p.normal.dot(q - p.origin);
        psum += r * r;
        add(q, p.normal, r, 1.0);
    }
    result.virtual_rms_m = vpairs.empty() ? 0.0 : std::sqrt(vsum / vpairs.size());
    result.real_rms_m = ppairs.empty() ? 0.0 : std::sqrt(psum / ppairs.size());
    result.rmse = std::sqrt((vsum + psum) / static_cast<double>(qs.size()));

    const std::size_t m = qs.size();
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (const auto &q : qs) centroid += q;
    centroid /= static_cast<double>(m);
    double spread = 0.0;
    for (const auto &q : qs) spread += (q - centroid).squaredNorm();
    spread = std::max(std::sqrt(spread / m), 1e-6);
    // H: information for a left perturbation [dt, dw] (d q / d dw = -[q]x). Hn: the same
    // about the centroid with rotation scaled by the feature spread, so that the degeneracy
    // test depends neither on where the frame origin lies nor on units.
    Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 6> Hn = Eigen::Matrix<double, 6, 6>::Zero();
    double wr2 = 0.0, wsum = 0.0;
    for (std::size_t i = 0; i < m; ++i) {
        Eigen::Matrix<double, 1, 6> J, Jn;
        J << dirs[i].transpose(), qs[i].cross(dirs[i]).transpose();
        Jn << dirs[i].transpose(), (qs[i] - centroid).cross(dirs[i]).transpose() / spread;
        H += wts[i] * J.transpose() * J;
        Hn += wts[i] * Jn.transpose() * Jn;
        wr2 += wts[i] * res[i] * res[i];
        wsum += wts[i];
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eig(Hn);
    const double emax = eig.eigenvalues().maxCoeff();
    const double emin = eig.eigenvalues().minCoeff();
    result.degenerate = !(emax > 0.0) || emin / emax < config.degenerate_eigen_ratio;
    const double dof = std::max(1.0, static_cast<double>(m) - 6.0);
    const double sigma2 = std::max(wr2 / wsum * m / dof, 1e-8);
    const Eigen::FullPivLU<Eigen::Matrix<double, 6, 6>> lu(H);
    if (lu.isInvertible()) {
        result.covariance = sigma2 * lu.inverse();
    } else {
        result.covariance = Matrix6d::Identity() * kUnobservedVariance;
        result.degenerate = true;
    }
    return result;
}

}  // namespace forestslam
