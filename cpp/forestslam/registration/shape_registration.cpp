#include "forestslam/registration/shape_registration.hpp"

#include <ceres/ceres.h>

#include <cmath>
#include <stdexcept>
#include <string>

namespace forestslam::registration {
namespace {

struct Gaussian2 {
    Eigen::Vector2d mean;
    Eigen::Matrix2d cov;
};

Gaussian2 marginal(const Eigen::Ref<const Points3> &means,
                   const Eigen::Ref<const Covariances> &covs, int i) {
    Gaussian2 g;
    g.mean = means.row(i).head<2>().transpose();
    g.cov << covs(i, 0), covs(i, 1), covs(i, 3), covs(i, 4);
    return g;
}

// Eq. 3 for all pairs; templated so Ceres autodiff gives the exact gradient.
struct ShapeCostFunctor {
    std::vector<Gaussian2> source, target;

    template <typename T>
    bool operator()(const T *const pose, T *cost) const {
        const T c = cos(pose[2]), s = sin(pose[2]);
        T sum(0.0);
        for (size_t k = 0; k < source.size(); ++k) {
            const auto &S = source[k];
            const auto &G = target[k];
            const T mx = c * S.mean.x() - s * S.mean.y() + pose[0] - G.mean.x();
            const T my = s * S.mean.x() + c * S.mean.y() + pose[1] - G.mean.y();
            // R Sigma_S R^T + Sigma_T
            const double a = S.cov(0, 0), b = S.cov(0, 1), d = S.cov(1, 1);
            const T r00 = c * c * a - T(2.0) * c * s * b + s * s * d + G.cov(0, 0);
            const T r01 = c * s * (a - d) + (c * c - s * s) * b + G.cov(0, 1);
            const T r11 = s * s * a + T(2.0) * c * s * b + c * c * d + G.cov(1, 1);
            const T det = r00 * r11 - r01 * r01;
            const T maha = (r11 * mx * mx - T(2.0) * r01 * mx * my + r00 * my * my) / det;
            sum -= exp(T(-0.5) * maha);
        }
        cost[0] = sum;
        return true;
    }
};

ShapeCostFunctor makeFunctor(const Eigen::Ref<const Points3> &sm,
                             const Eigen::Ref<const Covariances> &sc,
                             const Eigen::Ref<const Points3> &tm,
                             const Eigen::Ref<const Covariances> &tc,
                             const std::vector<std::pair<int, int>> &pairs,
                             const std::vector<int> &use, double min_sigma_m) {
    ShapeCostFunctor f;
    const Eigen::Matrix2d floor = Eigen::Matrix2d::Identity() * (0.5 * min_sigma_m * min_sigma_m);
    for (int k : use) {
        Gaussian2 s = marginal(sm, sc, pairs[k].first), t = marginal(tm, tc, pairs[k].second);
        s.cov += floor;  // half of the floor on each side: Sigma_i gets min_sigma^2 in total
        t.cov += floor;
        f.source.push_back(s);
        f.target.push_back(t);
    }
    return f;
}

bool validRows(const Eigen::Ref<const Points3> &m, const Eigen::Ref<const Covariances> &c, int i) {
    return m.row(i).allFinite() && c.row(i).allFinite();
}

// Pairs index rows of both sides (a wrong index is a caller's bug, not data to skip).
void checkPairs(const char *where, const std::vector<std::pair<int, int>> &pairs,
                Eigen::Index source_rows, Eigen::Index target_rows) {
    for (const auto &p : pairs) {
        if (p.first < 0 || p.first >= source_rows || p.second < 0 || p.second >= target_rows)
            throw std::invalid_argument(std::string(where) + ": pair (" + std::to_string(p.first) +
                                        ", " + std::to_string(p.second) + ") out of range for " +
                                        std::to_string(source_rows) + " source and " +
                                        std::to_string(target_rows) + " target stems");
    }
}

// One 3x3 covariance row per mean.
void checkCovariances(const char *where, const Eigen::Ref<const Points3> &means,
                      const Eigen::Ref<const Covariances> &covs, const char *side) {
    if (covs.rows() != means.rows())
        throw std::invalid_argument(std::string(where) + ": " + std::to_string(covs.rows()) + " " +
                                    side + " covariances for " + std::to_string(means.rows()) +
                                    " means");
}

}  // namespace

double shapeCost(const double pose[3], const Eigen::Ref<const Points3> &source_means,
                 const Eigen::Ref<const Covariances> &source_covs,
                 const Eigen::Ref<const Points3> &target_means,
                 const Eigen::Ref<const Covariances> &target_covs,
                 const std::vector<std::pair<int, int>> &pairs, double min_sigma_m,
                 double gradient[3]) {
    checkCovariances("shapeCost", source_means, source_covs, "source");
    checkCovariances("shapeCost", target_means, target_covs, "target");
    checkPairs("shapeCost", pairs, source_means.rows(), target_means.rows());
    std::vector<int> use(pairs.size());
    for (size_t k = 0; k < pairs.size(); ++k) use[k] = static_cast<int>(k);
    ceres::AutoDiffFirstOrderFunction<ShapeCostFunctor, 3> fn(new ShapeCostFunctor(makeFunctor(
        source_means, source_covs, target_means, target_covs, pairs, use, min_sigma_m)));
    double cost = 0.0;
    fn.Evaluate(pose, &cost, gradient);
    return cost;
}

std::pair<Pose3, std::vector<int>> consensusPairs(const Eigen::Ref<const Points3> &source,
                                                  const Eigen::Ref<const Points3> &target,
                                                  const std::vector<std::pair<int, int>> &pairs,
                                                  const Pose3 &T_init,
                                                  const ShapeRegistrationConfig &config) {
    checkPairs("consensusPairs", pairs, source.rows(), target.rows());
    const int n = static_cast<int>(pairs.size());
    const double thr2 = config.inlier_threshold_m * config.inlier_threshold_m;
    auto xy = [](const Eigen::Ref<const Points3> &p, int i) -> Eigen::Vector2d {
        return p.row(i).head<2>().transpose();
    };
    auto score = [&](const Eigen::Vector3d &pose, std::vector<int> &inliers, double &sse) {
        const Eigen::Rotation2Dd R(pose.z());
        inliers.clear();
        sse = 0.0;
        for (int k = 0; k < n; ++k) {
            const Eigen::Vector2d r =
                R * xy(source, pairs[k].first) + pose.head<2>() - xy(target, pairs[k].second);
            const double e = r.squaredNorm();
            if (e <= thr2) {
                inliers.push_back(k);
                sse += e;
            }
        }
    };
    Eigen::Vector3d best_pose = poseToPlanar(T_init);
    std::vector<int> best, cand;
    double best_sse = 0.0, sse = 0.0;
    score(best_pose, best, best_sse);
    int tried = 0;
    for (int a = 0; a < n && tried < config.max_consensus_pairs; ++a) {
        for (int b = a + 1; b < n && tried < config.max_consensus_pairs; ++b) {
            const Eigen::Vector2d s = xy(source, pairs[b].first) - xy(source, pairs[a].first);
            const Eigen::Vector2d t = xy(target, pairs[b].second) - xy(target, pairs[a].second);
            if (std::abs(s.norm() - t.norm()) > config.consensus_tolerance_m) continue;
            if (s.norm() < 2.0 * config.consensus_tolerance_m) continue;  // direction ill-defined
            ++tried;
            const double yaw = std::atan2(t.y(), t.x()) - std::atan2(s.y(), s.x());
            const Eigen::Rotation2Dd R(yaw);
            const Eigen::Vector2d mid_s =
                0.5 * (xy(source, pairs[a].first) + xy(source, pairs[b].first));
            const Eigen::Vector2d mid_t =
                0.5 * (xy(target, pairs[a].second) + xy(target, pairs[b].second));
            const Eigen::Vector3d pose(mid_t.x() - (R * mid_s).x(), mid_t.y() - (R * mid_s).y(),
                                       std::atan2(std::sin(yaw), std::cos(yaw)));
            score(pose, cand, sse);
            if (cand.size() > best.size() || (cand.size() == best.size() && sse < best_sse)) {
                best = cand;
                best_sse = sse;
                best_pose = pose;
            }
        }
    }
    return {planarToPose(best_pose.x(), best_pose.y(), best_pose.z()), best};
}

RegistrationResult registerShapes(const Eigen::Ref<const Points3> &source_means,
                                  const Eigen::Ref<const Covariances> &source_covs,
                                  const Eigen::Ref<const Points3> &target_means,
                                  const Eigen::Ref<const Covariances> &target_covs,
                                  const std::vector<std::pair<int, int>> &pairs_in,
                                  const Pose3 &T_init, const ShapeRegistrationConfig &config) {
    checkCovariances("registerShapes", source_means, source_covs, "source");
    checkCovariances("registerShapes", target_means, target_covs, "target");
    checkPairs("registerShapes", pairs_in, source_means.rows(), target_means.rows());
    RegistrationResult result;
    const Eigen::Vector3d init = poseToPlanar(T_init);
    result.T_target_source = planarToPose(init.x(), init.y(), init.z());
    result.covariance = Matrix6d::Identity() * kUnobservedVariance;
    // Keep only pairs of finite stems.
    std::vector<std::pair<int, int>> pairs;
    for (const auto &p : pairs_in) {
        if (validRows(source_means, source_covs, p.first) &&
            validRows(target_means, target_covs, p.second))
            pairs.push_back(p);
    }
    if (pairs.empty()) return result;

    auto [T0, inliers] = consensusPairs(source_means, target_means, pairs, T_init, config);
    result.inliers = static_cast<int>(inliers.size());
    if (inliers.empty()) return result;

    Eigen::Vector3d x = poseToPlanar(T0);
    auto *functor = new ShapeCostFunctor(makeFunctor(
        source_means, source_covs, target_means, target_covs, pairs, inliers, config.min_sigma_m));
    const ShapeCostFunctor model = *functor;  // kept for the covariance below
    ceres::GradientProblem problem(
        new ceres::AutoDiffFirstOrderFunction<ShapeCostFunctor, 3>(functor));
    ceres::GradientProblemSolver::Options options;
    options.max_num_iterations = config.max_iterations;
    options.logging_type = ceres::SILENT;
    options.function_tolerance = 1e-10;
    options.gradient_tolerance = 1e-12;
    options.parameter_tolerance = 1e-10;
    ceres::GradientProblemSolver::Summary summary;
    double params[3] = {x.x(), x.y(), x.z()};
    ceres::Solve(options, problem, params, &summary);
    result.iterations = static_cast<int>(summary.iterations.size());
    result.converged = summary.termination_type == ceres::CONVERGENCE ||
                       summary.termination_type == ceres::USER_SUCCESS;
    if (!std::isfinite(params[0]) || !std::isfinite(params[1]) || !std::isfinite(params[2])) {
        result.converged = false;
        return result;
    }
    result.T_target_source = planarToPose(params[0], params[1], params[2]);

    // Linearised covariance: (sum J_i^T Sigma_i^-1 J_i)^-1 with J_i = d mu_i / d(x, y, yaw).
    const double c = std::cos(params[2]), s = std::sin(params[2]);
    Eigen::Matrix2d R;
    R << c, -s, s, c;
    Eigen::Matrix3d info = Eigen::Matrix3d::Zero();
    double sse = 0.0;
    for (size_t k = 0; k < model.source.size(); ++k) {
        const auto &S = model.source[k];
        const auto &G = model.target[k];
        const Eigen::Vector2d p = R * S.mean;
        const Eigen::Matrix2d Sigma = R * S.cov * R.transpose() + G.cov;
        Eigen::Matrix<double, 2, 3> J;
        J << 1, 0, -p.y(), 0, 1, p.x();
        info += J.transpose() * Sigma.inverse() * J;
        sse += (p + Eigen::Vector2d(params[0], params[1]) - G.mean).squaredNorm();
    }
    result.rmse = std::sqrt(sse / model.source.size());
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(info);
    const bool well_posed = eig.eigenvalues()(0) > 1e-9 * std::max(1.0, eig.eigenvalues()(2));
    if (well_posed) {
        const Eigen::Matrix3d cov = info.inverse();
        const int idx[3] = {0, 1, 5};
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) result.covariance(idx[a], idx[b]) = cov(a, b);
    }
    result.degenerate = !well_posed || result.inliers < config.min_inliers_not_degenerate;
    return result;
}

}  // namespace forestslam::registration
