#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

#include "forestslam/common/circle_fit.hpp"

using forestslam::CircleFit;
using forestslam::CircleFitConfig;
using forestslam::Points2;

namespace {

// Points on an arc [a0, a1] (radians) of a circle, with Gaussian radial noise.
Points2 arc(double cx, double cy, double r, double a0, double a1, int n, double noise,
            unsigned seed) {
    std::mt19937 rng(seed);
    std::normal_distribution<double> g(0.0, noise);
    Points2 p(n, 2);
    for (int i = 0; i < n; ++i) {
        const double a = a0 + (a1 - a0) * i / std::max(1, n - 1);
        const double rr = r + (noise > 0 ? g(rng) : 0.0);
        p.row(i) << cx + rr * std::cos(a), cy + rr * std::sin(a);
    }
    return p;
}

}  // namespace

TEST(CircleFit, ExactFullCircle) {
    const Points2 p = arc(3.0, -2.0, 0.25, 0.0, 2 * M_PI * 0.99, 60, 0.0, 1);
    const CircleFit f = forestslam::fitCircle(p);
    ASSERT_TRUE(f.valid);
    EXPECT_NEAR(f.centre.x(), 3.0, 1e-6);
    EXPECT_NEAR(f.centre.y(), -2.0, 1e-6);
    EXPECT_NEAR(f.radius, 0.25, 1e-6);
    EXPECT_EQ(f.inliers, 60);
    EXPECT_LT(f.rms_m, 1e-6);
    EXPECT_GT(f.arc_coverage, 0.95);
    const CircleFit a = forestslam::fitCircleAlgebraic(p);
    ASSERT_TRUE(a.valid);
    EXPECT_NEAR(a.radius, 0.25, 1e-6);
}

TEST(CircleFit, NoisyThirdOfAStemAsALidarSeesIt) {
    // 120 deg arc, 5 mm noise, radius 0.15 m, far from the origin.
    double worst = 0.0;
    for (unsigned seed = 0; seed < 20; ++seed) {
        const Points2 p = arc(12.0, 7.0, 0.15, 1.0, 1.0 + 2 * M_PI / 3, 40, 0.005, seed);
        CircleFitConfig o;
        o.inlier_threshold_m = 0.015;
        const CircleFit f = forestslam::fitCircle(p, o);
        ASSERT_TRUE(f.valid);
        worst = std::max(worst, std::abs(f.radius - 0.15));
        EXPECT_NEAR(f.arc_coverage, 1.0 / 3.0, 0.06);
        EXPECT_NEAR(f.rms_m, 0.005, 0.003);
    }
    EXPECT_LT(worst, 0.02);  // radius within 2 cm on every seed
}

TEST(CircleFit, RobustToOutliers) {
    Points2 p = arc(1.0, 1.0, 0.2, -1.0, 1.5, 50, 0.003, 7);
    Points2 all(80, 2);
    all.topRows(50) = p;
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> u(0.5, 1.7);
    for (int i = 50; i < 80; ++i) all.row(i) << u(rng), u(rng);  // 37 % clutter (branches)
    CircleFitConfig o;
    o.inlier_threshold_m = 0.01;
    const CircleFit f = forestslam::fitCircle(all, o);
    ASSERT_TRUE(f.valid);
    EXPECT_NEAR(f.centre.x(), 1.0, 0.01);
    EXPECT_NEAR(f.centre.y(), 1.0, 0.01);
    EXPECT_NEAR(f.radius, 0.2, 0.01);
    EXPECT_GE(f.inliers, 48);
    EXPECT_LE(f.inliers, 56);
    // The plain algebraic fit is pulled away by the clutter: robustness matters.
    const CircleFit a = forestslam::fitCircleAlgebraic(all);
    EXPECT_GT(std::abs(a.radius - 0.2) + (a.centre - Eigen::Vector2d(1, 1)).norm(), 0.03);
}

TEST(CircleFit, DegenerateInputIsInvalidNotACrash) {
    EXPECT_FALSE(forestslam::fitCircle(Points2(0, 2)).valid);
    Points2 two(2, 2);
    two << 0, 0, 1, 1;
    EXPECT_FALSE(forestslam::fitCircle(two).valid);
    EXPECT_FALSE(forestslam::fitCircleAlgebraic(two).valid);
    Points2 line(20, 2);
    for (int i = 0; i < 20; ++i) line.row(i) << 0.1 * i, 0.5 + 0.2 * i;
    EXPECT_FALSE(forestslam::fitCircle(line).valid);
    EXPECT_FALSE(forestslam::fitCircleAlgebraic(line).valid);
    Points2 same(10, 2);
    same.setConstant(2.0);
    EXPECT_FALSE(forestslam::fitCircle(same).valid);
    Points2 nan(5, 2);
    nan.setConstant(std::numeric_limits<double>::quiet_NaN());
    EXPECT_FALSE(forestslam::fitCircle(nan).valid);
}

TEST(CircleFit, NonFiniteRowsAreIgnoredAndIndicesReferToInput) {
    Points2 p = arc(0.0, 0.0, 0.3, 0.0, 3.0, 30, 0.0, 1);
    p(4, 0) = std::numeric_limits<double>::quiet_NaN();
    const CircleFit f = forestslam::fitCircle(p);
    ASSERT_TRUE(f.valid);
    EXPECT_NEAR(f.radius, 0.3, 1e-6);
    EXPECT_EQ(f.inliers, 29);
    for (int i : f.inlier_indices) EXPECT_NE(i, 4);
}

TEST(CircleFit, RadiusBoundsRejectImpossibleFits) {
    const Points2 p = arc(0.0, 0.0, 2.0, 0.0, 1.0, 30, 0.0, 1);  // a 4 m "stem"
    CircleFitConfig o;
    o.max_radius_m = 1.0;
    EXPECT_FALSE(forestslam::fitCircle(p, o).valid);
    o.max_radius_m = 3.0;
    EXPECT_TRUE(forestslam::fitCircle(p, o).valid);
}

TEST(CircleFit, ArcCoverageCountsOccupiedSectors) {
    Points2 p(2, 2);
    p << 1, 0.01, -1, 0.01;  // two opposite sectors out of 4
    EXPECT_DOUBLE_EQ(forestslam::arcCoverage(p, {0, 1}, Eigen::Vector2d::Zero(), 4), 0.5);
    EXPECT_DOUBLE_EQ(forestslam::arcCoverage(p, {}, Eigen::Vector2d::Zero(), 4), 0.0);
    EXPECT_THROW(forestslam::arcCoverage(p, {0, 2}, Eigen::Vector2d::Zero(), 4), std::out_of_range);
    EXPECT_THROW(forestslam::arcCoverage(p, {0}, Eigen::Vector2d::Zero(), 0),
                 std::invalid_argument);
}

namespace {

// What a LiDAR at `origin` sees of a circle: beams evenly across the visible side, each point
// off the circle along its beam by Gaussian range noise.
void rangeNoisyView(const Eigen::Vector2d &centre, double r, const Eigen::Vector2d &origin, int n,
                    double noise, std::mt19937 &rng, std::vector<Eigen::Vector2d> &pts,
                    std::vector<Eigen::Vector2d> &origins) {
    std::normal_distribution<double> g(0.0, noise);
    const Eigen::Vector2d to = centre - origin;
    const double d = to.norm(), half = std::asin(r / d), bearing = std::atan2(to.y(), to.x());
    for (int i = 0; i < n; ++i) {
        const double b = bearing - half + 2 * half * (i + 0.5) / n;
        const Eigen::Vector2d u(std::cos(b), std::sin(b));
        const double a = u.dot(to), q = r * r - (to.squaredNorm() - a * a);
        if (q < 0) continue;
        pts.push_back(origin + (a - std::sqrt(q) + g(rng)) * u);
        origins.push_back(origin);
    }
}

}  // namespace

TEST(CircleFit, RangeNoiseOnOneSidedArcsBiasesTheOrthogonalFitNotTheRayFit) {
    // 3 cm range noise, one view per stem from 6 m (a VLP-16 scan): the orthogonal fit shrinks
    // the stem by about 1 cm in radius; the range model must stay within 2 mm on average.
    std::mt19937 rng(5);
    double bias_ortho = 0, bias_rays = 0;
    const int trials = 20;
    for (int t = 0; t < trials; ++t) {
        const double r = 0.06 + 0.01 * t;
        std::vector<Eigen::Vector2d> pts, origins;
        rangeNoisyView({6.0, 1.0}, r, {0.0, 0.0}, 400, 0.03, rng, pts, origins);
        Points2 xy(static_cast<Eigen::Index>(pts.size()), 2), o(xy.rows(), 2);
        for (size_t i = 0; i < pts.size(); ++i) {
            xy.row(static_cast<Eigen::Index>(i)) = pts[i].transpose();
            o.row(static_cast<Eigen::Index>(i)) = origins[i].transpose();
        }
        const CircleFit ortho = forestslam::fitCircle(xy);
        const CircleFit rays = forestslam::fitCircleRays(xy, o);
        ASSERT_TRUE(ortho.valid && rays.valid);
        bias_ortho += (ortho.radius - r) / trials;
        bias_rays += (rays.radius - r) / trials;
    }
    EXPECT_LT(bias_ortho, -0.005);
    EXPECT_LT(std::abs(bias_rays), 0.002);
}

TEST(CircleFit, RayFitNeedsOneOriginPerPoint) {
    const Points2 p = arc(3.0, -2.0, 0.25, 0.0, 2.0, 40, 0.0, 1);
    // A wrong row count is an error, not a silent fall back to the orthogonal fit.
    EXPECT_THROW(forestslam::fitCircleRays(p, Points2(3, 2)), std::invalid_argument);
    // Exact points seen from one origin: the range model keeps the exact circle.
    const Points2 o = Eigen::RowVector2d(-5.0, -2.0).replicate(p.rows(), 1);
    const CircleFit c = forestslam::fitCircleRays(p, o);
    ASSERT_TRUE(c.valid);
    EXPECT_NEAR(c.radius, 0.25, 1e-4);
}

// The fit's covariance predicts the spread of the radius over noise draws, and grows on a
// short arc, where centre and radius trade off.
TEST(CircleFit, RadiusStdPredictsTheSpreadOfFitsAndGrowsOnShortArcs) {
    double predicted[2], spread[2];
    const double half[2] = {M_PI, M_PI / 4};
    for (int k = 0; k < 2; ++k) {
        double sum = 0, sum2 = 0, std_sum = 0;
        const int draws = 80;
        for (int s = 0; s < draws; ++s) {
            const CircleFit f =
                forestslam::fitCircle(arc(0.0, 0.0, 0.15, -half[k], half[k], 80, 0.005, 100 + s));
            ASSERT_TRUE(f.valid);
            sum += f.radius, sum2 += f.radius * f.radius, std_sum += f.radiusStd();
        }
        predicted[k] = std_sum / draws;
        spread[k] = std::sqrt(sum2 / draws - (sum / draws) * (sum / draws));
    }
    EXPECT_GT(predicted[1], 5 * predicted[0]);
    for (int k = 0; k < 2; ++k) {
        EXPECT_GT(predicted[k], 0.6 * spread[k]);
        EXPECT_LT(predicted[k], 1.6 * spread[k]);
    }
}

TEST(CircleFit, CovarianceNeedsMoreRowsThanFittedParameters) {
    const Points2 p = arc(1.0, 2.0, 0.2, 0.0, 2.0, 4, 0.001, 3);
    const std::vector<int> three = {0, 1, 2}, four = {0, 1, 2, 3};
    EXPECT_TRUE(std::isinf(forestslam::circleCovariance(p, three, {1.0, 2.0}, 0.2)(2, 2)));
    EXPECT_TRUE(std::isfinite(forestslam::circleCovariance(p, four, {1.0, 2.0}, 0.2)(2, 2)));
    // the same circle only evaluated on the rows (fitted elsewhere): residuals over n, not n - 3
    const double fitted = forestslam::circleCovariance(p, four, {1.0, 2.0}, 0.2, 3)(2, 2);
    const double evaluated = forestslam::circleCovariance(p, four, {1.0, 2.0}, 0.2, 0)(2, 2);
    EXPECT_NEAR(evaluated, fitted * (4.0 - 3.0) / 4.0, 1e-12 * fitted);
    EXPECT_TRUE(std::isinf(forestslam::fitCircle(arc(0, 0, 0.2, 0, 1, 2, 0, 1)).radiusStd()));
}

namespace {

// Rows of xy repeated by integer counts.
Points2 repeated(const Points2 &xy, const Eigen::VectorXd &counts) {
    Points2 out(static_cast<Eigen::Index>(counts.sum()), 2);
    Eigen::Index k = 0;
    for (Eigen::Index i = 0; i < xy.rows(); ++i)
        for (int c = 0; c < static_cast<int>(counts(i)); ++c) out.row(k++) = xy.row(i);
    return out;
}

}  // namespace

// Integer weights give the fit of the rows repeated that often (RANSAC draw for draw, the
// same circle, rms and covariance), without the copies; a zero weight drops a row.
TEST(CircleFit, IntegerWeightsFitAsTheRowsRepeated) {
    std::mt19937 rng(9);
    std::uniform_int_distribution<int> count(1, 6);
    Points2 xy = arc(2.0, 1.0, 0.18, -1.2, 1.6, 70, 0.01, 4);
    xy.row(5) << 2.4, 1.3;  // an outlier
    Eigen::VectorXd w(xy.rows());
    for (Eigen::Index i = 0; i < w.size(); ++i) w(i) = count(rng);
    const Points2 rep = repeated(xy, w);
    const CircleFit a = forestslam::fitCircleWeighted(xy, w), b = forestslam::fitCircle(rep);
    ASSERT_TRUE(a.valid && b.valid);
    EXPECT_NEAR(a.radius, b.radius, 1e-9);
    EXPECT_NEAR((a.centre - b.centre).norm(), 0.0, 1e-9);
    EXPECT_NEAR(a.rms_m, b.rms_m, 1e-9);
    EXPECT_LT((a.covariance - b.covariance).cwiseAbs().maxCoeff(), 1e-9 * b.covariance.norm());
    // Seen from one side under range noise: the range model agrees as well.
    const Points2 o = Eigen::RowVector2d(-4.0, 0.5).replicate(xy.rows(), 1);
    const CircleFit ra = forestslam::fitCircleRaysWeighted(xy, o, w);
    const CircleFit rb = forestslam::fitCircleRays(rep, repeated(o, w));
    ASSERT_TRUE(ra.valid && rb.valid);
    EXPECT_NEAR(ra.radius, rb.radius, 1e-9);
    EXPECT_NEAR((ra.centre - rb.centre).norm(), 0.0, 1e-9);
    // Unit weights are the unweighted fit.
    const CircleFit u = forestslam::fitCircleWeighted(xy, Eigen::VectorXd::Ones(xy.rows()));
    EXPECT_NEAR(u.radius, forestslam::fitCircle(xy).radius, 1e-12);
}

// Weights pull the circle to the rows observed most: two concentric rings of points, the inner
// one observed ten times as often, give the inner circle (unweighted: the ring in between).
TEST(CircleFit, WeightsPullTheCircleToTheRowsObservedMost) {
    const Points2 inner = arc(0.0, 0.0, 0.15, 0.0, 2 * M_PI * 0.98, 60, 0.0, 1);
    const Points2 outer = arc(0.0, 0.0, 0.17, 0.05, 2 * M_PI * 0.98 + 0.05, 60, 0.0, 1);
    Points2 both(120, 2);
    both << inner, outer;
    Eigen::VectorXd w(120);
    w << Eigen::VectorXd::Constant(60, 10.0), Eigen::VectorXd::Ones(60);
    CircleFitConfig o;
    o.inlier_threshold_m = 0.03;  // both rings are inliers of either circle
    const CircleFit plain = forestslam::fitCircle(both, o);
    const CircleFit weighted = forestslam::fitCircleWeighted(both, w, o);
    ASSERT_TRUE(plain.valid && weighted.valid);
    EXPECT_NEAR(plain.radius, 0.16, 0.002);
    EXPECT_NEAR(weighted.radius, 0.15 + 0.02 / 11.0, 0.002);
    // Non-integer weights (e.g. square roots of counts) work the same way.
    const CircleFit root = forestslam::fitCircleWeighted(both, w.cwiseSqrt(), o);
    ASSERT_TRUE(root.valid);
    EXPECT_NEAR(root.radius, 0.15 + 0.02 / (1.0 + std::sqrt(10.0)), 0.002);
    EXPECT_THROW(forestslam::fitCircleWeighted(both, Eigen::VectorXd::Ones(3)),
                 std::invalid_argument);
    w(0) = -1.0;
    EXPECT_THROW(forestslam::fitCircleWeighted(both, w, o), std::invalid_argument);
}

// The arc jackknife sees the shape the covariance takes for white noise: a third of an oval
// (10 % ovality, the axes 0.2 / 0.18 m) fits a circle whose radius depends on which part of
// the arc is seen; a third of a circle under the same 2 mm noise does not. It is independent
// of the rows' order, and infinite when the inliers cannot fill the blocks.
TEST(CircleFit, ArcJackknifeSeesTheShapeNotTheRowOrder) {
    const int n = 90;
    std::mt19937 rng(5);
    std::normal_distribution<double> g(0.0, 0.002);
    Points2 oval(n, 2);
    for (int i = 0; i < n; ++i) {
        const double a = -0.2 + 2.1 * i / (n - 1.0);
        oval.row(i) << 0.2 * std::cos(a) + g(rng), 0.18 * std::sin(a) + g(rng);
    }
    const Points2 round = arc(0.0, 0.0, 0.19, -0.2, 1.9, n, 0.002, 5);
    const Eigen::VectorXd w = Eigen::VectorXd::LinSpaced(n, 1.0, 3.0);
    CircleFitConfig o;
    o.inlier_threshold_m = 0.02;
    const CircleFit fo = forestslam::fitCircleWeighted(oval, w, o);
    const CircleFit fr = forestslam::fitCircleWeighted(round, w, o);
    ASSERT_TRUE(fo.valid && fr.valid);
    const double jo = forestslam::circleArcJackknife(oval, w, fo.centre, fo.radius, 6, o);
    const double jr = forestslam::circleArcJackknife(round, w, fr.centre, fr.radius, 6, o);
    EXPECT_LT(jr, 0.003);
    EXPECT_GT(jo, 3.0 * jr);
    EXPECT_GT(jo, 3.0 * fo.radiusStd());  // the covariance takes the bend for noise
    // Rows in another order: the same value.
    std::vector<int> perm(n);
    for (int i = 0; i < n; ++i) perm[i] = (i * 37 + 11) % n;
    Points2 shuffled(n, 2);
    Eigen::VectorXd ws(n);
    for (int i = 0; i < n; ++i) shuffled.row(i) = oval.row(perm[i]), ws(i) = w(perm[i]);
    EXPECT_EQ(forestslam::circleArcJackknife(shuffled, ws, fo.centre, fo.radius, 6, o), jo);
    // Too few inliers for the blocks.
    EXPECT_TRUE(std::isinf(
        forestslam::circleArcJackknife(oval.topRows(11), w.head(11), fo.centre, fo.radius, 6, o)));
    EXPECT_THROW(forestslam::circleArcJackknife(oval, w.head(3), fo.centre, fo.radius, 6, o),
                 std::invalid_argument);
}
