#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "forestslam/localization/acceptance.hpp"

using forestslam::Points2;

namespace {

struct ClosenessStats {
    double mean = 0;    // mean closeness of the chance landings
    double above3 = 0;  // share of them scoring above 3
};

// Closeness of 20,000 chance landings, uniform in the gate's disc around the predicted position
// (offset r at angle a), scored by the radius radiusOf(r, a) (seeded).
template <class RadiusOf>
ClosenessStats chanceCloseness(unsigned seed, double density, double gate, RadiusOf radiusOf) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0, 1);
    const int n = 20000;
    ClosenessStats stats;
    for (int i = 0; i < n; ++i) {
        const double r = gate * std::sqrt(u(rng)), a = 2 * 3.14159265358979 * u(rng);
        const double v = forestslam::localization::closeness(density, radiusOf(r, a), gate, 0.0);
        stats.mean += v / n;
        stats.above3 += (v > 3) / double(n);
    }
    return stats;
}

}  // namespace

TEST(Acceptance, PoissonTailKnownValues) {
    // P(X >= 1) = 1 - e^-mu; P(X >= 2) = 1 - e^-mu (1 + mu).
    EXPECT_NEAR(forestslam::localization::poissonTailLog10(0.5, 1), -std::log10(1 - std::exp(-0.5)),
                1e-12);
    EXPECT_NEAR(forestslam::localization::poissonTailLog10(2.0, 2),
                -std::log10(1 - 3 * std::exp(-2.0)), 1e-12);
    EXPECT_EQ(forestslam::localization::poissonTailLog10(2.0, 0), 0.0);
    // Far tail: P(X >= 30 | mu = 1) ~ e^-1 / 30! within a few percent.
    EXPECT_NEAR(forestslam::localization::poissonTailLog10(1.0, 30),
                (1 + std::lgamma(31.0)) / std::log(10.0), 0.02);
}

TEST(Acceptance, DensityOfAUniformGrid) {
    // One trunk per 2 m x 2 m: 0.25 per m^2 inside, less at the border, none far away.
    Points2 xy(50 * 50, 2);
    for (int i = 0; i < 50; ++i)
        for (int j = 0; j < 50; ++j) xy.row(i * 50 + j) << 2.0 * i + 1, 2.0 * j + 1;
    const forestslam::localization::DensityGrid grid(xy);
    EXPECT_NEAR(grid.at(50, 50), 0.25, 1e-9);
    EXPECT_LT(grid.at(1, 1), 0.25);
    EXPECT_EQ(grid.at(500, 500), 0.0);
    EXPECT_NEAR(forestslam::localization::chanceRate(0.25, 0.5), 1 - std::exp(-0.25 * M_PI * 0.25),
                1e-12);
}

TEST(Acceptance, SeedsAndSearchAreDiscounted) {
    using forestslam::localization::chanceEvidence;
    const auto base = chanceEvidence(14, 20, 1.0, 6, 1);
    EXPECT_NEAR(base.expected, 1.0 * 14 / 20, 1e-12);  // the 6 seed trunks carry no evidence
    EXPECT_NEAR(chanceEvidence(14, 20, 1.0, 6, 1000).significance, base.significance - 3, 1e-9);
    EXPECT_NEAR(chanceEvidence(6, 20, 1.0, 6, 1).significance, 0.0, 1e-12);
    EXPECT_GT(chanceEvidence(14, 20, 1.0, 3, 1).significance, base.significance);
}

TEST(Acceptance, JudgeGivesTheReason) {
    forestslam::localization::AcceptanceConfig cfg;
    auto e = forestslam::localization::chanceEvidence(20, 30, 0.5, 6, 10);
    EXPECT_TRUE(forestslam::localization::judge(e, 0.3, cfg).accepted);
    EXPECT_NE(forestslam::localization::judge(e, 0.9, cfg).reason.find("ambiguous"),
              std::string::npos);
    e = forestslam::localization::chanceEvidence(9, 30, 6.0, 6,
                                                 10);  // a dense map explains 9 inliers
    EXPECT_NE(forestslam::localization::judge(e, 0.0, cfg).reason.find("not significant"),
              std::string::npos);
    e = forestslam::localization::chanceEvidence(5, 5, 0.0, 3, 1);
    EXPECT_EQ(forestslam::localization::judge(e, 0.0, cfg).reason, "too few inliers");
}

TEST(Acceptance, TruncatedProductTailKnownValue) {
    // One inlier (k = 1) with closeness w <= c: S >= c + w when one term's Exp(1) exceeds w, or
    // when two or more terms (each >= c) occur: P = mu e^-mu e^-w + P(N >= 2).
    const double mu = 0.1, c = 3.0, w = 2.0;
    const double p = mu * std::exp(-mu) * std::exp(-w) + 1 - std::exp(-mu) * (1 + mu);
    EXPECT_NEAR(forestslam::localization::truncatedProductTailLog10(mu, c, 1, w), -std::log10(p),
                1e-9);
    EXPECT_EQ(forestslam::localization::truncatedProductTailLog10(mu, c, 0, 5.0), 0.0);
    // Against the direct sum of Pois(j) P(Gamma(j) >= s - j c) (scipy.stats, 400 terms).
    EXPECT_NEAR(forestslam::localization::truncatedProductTailLog10(2.0, 2.1, 10, 12.5), 4.529518,
                1e-5);
    EXPECT_NEAR(forestslam::localization::truncatedProductTailLog10(15.0, 1.9, 30, 40.0), 4.180385,
                1e-5);
    EXPECT_NEAR(forestslam::localization::truncatedProductTailLog10(0.08, 4.5, 2, 9.0), 4.720768,
                1e-5);
    // Closer inliers are more significant; more of them too.
    EXPECT_GT(forestslam::localization::truncatedProductTailLog10(0.5, 3, 3, 9),
              forestslam::localization::truncatedProductTailLog10(0.5, 3, 3, 2));
    EXPECT_GT(forestslam::localization::truncatedProductTailLog10(0.5, 3, 4, 2),
              forestslam::localization::truncatedProductTailLog10(0.5, 3, 3, 2));
}

TEST(Acceptance, ClosenessOfChanceInliersIsExponential) {
    // Chance inliers land uniformly in the gate's disc: -ln(U / p) is Exp(1) (mean 1, and
    // P(> 3) = e^-3), so the test's null model holds; a fit within the noise floor scores high.
    const double density = 0.05, gate = 0.5;
    const ClosenessStats chance =
        chanceCloseness(11, density, gate, [](double r, double) { return r; });
    EXPECT_NEAR(chance.mean, 1.0, 0.03);
    EXPECT_NEAR(chance.above3, std::exp(-3.0), 0.005);
    EXPECT_NEAR(forestslam::localization::closeness(density, 0.0, gate, 0.05),
                forestslam::localization::closeness(density, 0.05, gate, 0.05),
                1e-12);  // the noise floor
    EXPECT_EQ(forestslam::localization::closeness(density, 0.7, gate, 0.05), 0.0);
}

TEST(Acceptance, ClosenessMakesAFewTightInliersSignificant) {
    using forestslam::localization::chanceEvidence;
    // A sparse map (chance rate 0.01 per trunk): 2 inliers beyond the seeds, with and without
    // knowing they landed within centimetres.
    const double w = 2 * forestslam::localization::closeness(0.0127, 0.05, 0.5, 0.02);
    const auto counted = chanceEvidence(5, 8, 0.08, 3, 10);
    const auto close = chanceEvidence(5, 8, 0.08, 3, 10, w);
    EXPECT_GT(close.significance, counted.significance + 1.0);
    // Inliers spread over the gate (closeness ~ 1 each, its mean by chance) gain little.
    EXPECT_LT(chanceEvidence(5, 8, 0.08, 3, 10, 2.0).significance, counted.significance + 0.5);
}

TEST(Acceptance, SeedEvidenceOfChanceMatchesIsExponential) {
    // A chance seed match: its m edge differences anywhere in the ball of the tolerance, so
    // P(norm <= d) = (d / R)^m and -ln of it is Exp(1); the noise floor bounds a true match.
    using forestslam::localization::seedEvidence;
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(0, 1);
    for (const int m : {3, 9}) {
        double sum = 0;
        int above2 = 0;
        const int n = 20000;
        for (int i = 0; i < n; ++i) {
            // Uniform in the m-ball of radius 0.35: the norm is R u^(1/m).
            const double norm = 0.35 * std::pow(u(rng), 1.0 / m);
            const double v = seedEvidence(norm, 0.35, m, 0.0);
            sum += v;
            above2 += v > 2;
        }
        EXPECT_NEAR(sum / n, 1.0, 0.03) << m;
        EXPECT_NEAR(double(above2) / n, std::exp(-2.0), 0.006) << m;
    }
    EXPECT_NEAR(seedEvidence(0.035, 0.35, 3, 0.0), 3 * std::log(10.0), 1e-12);
    EXPECT_EQ(seedEvidence(0.0, 0.35, 3, 0.02), seedEvidence(0.02 * std::sqrt(3.0), 0.35, 3, 0));
    EXPECT_EQ(seedEvidence(0.5, 0.35, 3, 0.02), 0.0);
}

TEST(Acceptance, SeedEvidenceJoinsTheTailAsOneMoreTerm) {
    using forestslam::localization::chanceEvidence;
    using forestslam::localization::truncatedProductTailLog10;
    // No chance inliers possible (mu = 0): the tail is the seed term's own, P(Exp(1) >= w).
    EXPECT_NEAR(truncatedProductTailLog10(0.0, 3.0, 0, 4.0, 1), 4.0 / std::log(10.0), 1e-9);
    // k = 0 chance inliers, one extra term: P = e^-mu e^-w + sum_{j>=1} Pois(j) Q(j+1, w - j c);
    // with w < c every j >= 1 term exceeds w surely: P = e^-mu e^-w + 1 - e^-mu.
    const double mu = 0.05, c = 3.0, w = 2.0;
    const double p = std::exp(-mu) * std::exp(-w) + 1 - std::exp(-mu);
    EXPECT_NEAR(truncatedProductTailLog10(mu, c, 0, w, 1), -std::log10(p), 1e-9);
    // A tight seed match makes the same inliers more significant, in both tails; none: as before.
    const auto plain = chanceEvidence(5, 8, 0.08, 3, 10, 4.0);
    EXPECT_GT(chanceEvidence(5, 8, 0.08, 3, 10, 4.0, 4.0).significance, plain.significance + 0.5);
    EXPECT_EQ(chanceEvidence(5, 8, 0.08, 3, 10, 4.0, 0.0).significance, plain.significance);
    const auto counted = chanceEvidence(5, 8, 0.08, 3, 10);
    EXPECT_GT(chanceEvidence(5, 8, 0.08, 3, 10, -1.0, 4.0).significance,
              counted.significance + 0.5);
    // An uninformative seed (evidence ~ its mean, 1 nat) costs a little: the search pays for it.
    EXPECT_LT(chanceEvidence(5, 8, 0.08, 3, 10, 4.0, 1.0).significance, plain.significance + 0.3);
}

TEST(Acceptance, GammaTail) {
    using forestslam::localization::gammaTailLn;
    // P(Gamma(1) >= x) = e^-x; P(Gamma(2) >= x) = e^-x (1 + x); P(Gamma(3) >= x) adds x^2 / 2.
    EXPECT_NEAR(gammaTailLn(1, 3.0), -3.0, 1e-12);
    EXPECT_NEAR(gammaTailLn(2, 3.0), -3.0 + std::log(4.0), 1e-12);
    EXPECT_NEAR(gammaTailLn(3, 5.0), -5.0 + std::log(1 + 5.0 + 12.5), 1e-12);
    EXPECT_EQ(gammaTailLn(3, 0.0), 0.0);
}

TEST(Acceptance, DbhLikelihoodRatioIsAnEValue) {
    using forestslam::localization::dbhEvidence;
    using forestslam::localization::dbhLogRatio;
    // A chance match's map trunk is any of its neighbourhood: the ratio's mean over them is
    // exactly 1 whatever the query's DBH (calibrated), and a matching DBH gains.
    const std::vector<float> nb = {0.12f, 0.18f, 0.2f, 0.25f, 0.31f, 0.33f, 0.4f, 0.52f};
    for (double d : {0.05, 0.2, 0.32, 0.45, 0.9}) {
        double mean = 0;
        for (float m : nb) mean += std::exp(dbhLogRatio(d, m, nb, 0.03, 0.1)) / nb.size();
        EXPECT_NEAR(mean, 1.0, 1e-9) << d;
    }
    EXPECT_GT(dbhLogRatio(0.52, 0.52, nb, 0.03, 0.1), std::log(4.0));          // an isolated DBH
    EXPECT_NEAR(dbhLogRatio(0.12, 0.52, nb, 0.03, 0.1), std::log(0.1), 1e-6);  // gross: eps
    EXPECT_EQ(dbhLogRatio(0.3, 0.3, {}, 0.03, 0.1), 0.0);
    // The whole query's evidence: a quarter of the product and 3/4 of 1, so useless DBHs cost
    // at most ln(4/3).
    EXPECT_NEAR(dbhEvidence(0.0), 0.0, 1e-12);
    EXPECT_NEAR(dbhEvidence(-50.0), std::log(0.75), 1e-12);
    EXPECT_NEAR(dbhEvidence(std::log(9.0)), std::log(3.0), 1e-12);
    EXPECT_NEAR(dbhEvidence(800.0), 800.0 - std::log(4.0), 1e-9);
    EXPECT_NEAR(dbhEvidence(std::log(9.0), 0.5), std::log(5.0), 1e-12);
}

namespace {
// Rows (0,0), (1,0), (0,1) and `p` on the local side; the map side the same, p's moved by e.
double farTrunkRadius(const Eigen::Vector2d &p, const Eigen::Vector2d &e) {
    forestslam::Points2 local(4, 2), map(4, 2);
    local << 0, 0, 1, 0, 0, 1, p.x(), p.y();
    map = local;
    map.row(3) += e.transpose();
    const std::vector<std::pair<int, int>> pairs = {{0, 0}, {1, 1}, {2, 2}, {3, 3}};
    return forestslam::localization::leaveOneOutRadii(local, map, pairs)[3];
}
}  // namespace

TEST(Acceptance, LeaveOneOutRadiusIsTheResidualAtTheCentroid) {
    // Four exact trunks around a fifth off by (0.1, 0.05): the fit to the four is exact and the
    // fifth, at their centroid, has no lever arm: its radius is its plain residual.
    forestslam::Points2 local(5, 2), map(5, 2);
    local << 5, 5, -5, 5, -5, -5, 5, -5, 0, 0;
    map = local;
    map.row(4) << 0.1, 0.05;
    std::vector<std::pair<int, int>> pairs;
    for (int i = 0; i < 5; ++i) pairs.emplace_back(i, i);
    const auto radii = forestslam::localization::leaveOneOutRadii(local, map, pairs);
    ASSERT_EQ(radii.size(), 5u);
    EXPECT_NEAR(radii[4], std::hypot(0.1, 0.05), 1e-9);
    EXPECT_TRUE(forestslam::localization::leaveOneOutRadii(local.topRows(3), map.topRows(3),
                                                           {{0, 0}, {1, 1}, {2, 2}})
                    .empty());
}

TEST(Acceptance, LeaveOneOutRadiusDiscountsTheLeverArm) {
    // A trunk 20 m from a 1 m seed triangle: the triangle's rotation error moves it along its
    // arc, so an error along the arc is less surprising than the same error towards the seeds.
    const Eigen::Vector2d far(20, 0);
    const double along = farTrunkRadius(far, {0, 0.2}), towards = farTrunkRadius(far, {0.2, 0});
    EXPECT_LT(along, 0.2 / 3);
    EXPECT_GT(towards, 0.2);
}

TEST(Acceptance, LeaveOneOutRadiiOfChanceLandingsAreConservative) {
    // Under a chance pose the map trunk lies anywhere in the gate around a far trunk's predicted
    // position: the closeness of its radius is at most Exp(1) (mean <= 1, P(> 3) <= e^-3).
    const ClosenessStats chance = chanceCloseness(5, 0.02, 0.5, [](double r, double a) {
        return farTrunkRadius({15, 3}, {r * std::cos(a), r * std::sin(a)});
    });
    EXPECT_LT(chance.mean, 1.0 + 0.03);
    EXPECT_LT(chance.above3, std::exp(-3.0) + 0.005);
}

TEST(Acceptance, SeedEvidenceInTheSearchedCubeIsExponentialAndSharper) {
    // The triangle search finds every map shape whose sides are each within the tolerance h (a
    // cube of side 2h): a chance match's differences are uniform in it, so the ball's volume
    // over the cube's is the exact p-value, -ln of it Exp(1); sharper than the inscribed ball's
    // (d / h)^m by m ln 2 - ln V_m(1) (0.65 nats for a triangle).
    using forestslam::localization::seedEvidence;
    using forestslam::localization::seedEvidenceCube;
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> u(-0.35, 0.35);
    double sum = 0;
    int above2 = 0;
    const int n = 20000;
    for (int i = 0; i < n; ++i) {
        const Eigen::Vector3d diff(u(rng), u(rng), u(rng));
        const double v = seedEvidenceCube(diff.norm(), 0.35, 3, 0.0);
        sum += v;
        above2 += v > 2;
    }
    // Corners beyond the ball of radius h score 0 (conservative): mean and tail at most Exp(1)'s.
    EXPECT_LT(sum / n, 1.0 + 0.02);
    EXPECT_GT(sum / n, 0.8);
    EXPECT_LT(double(above2) / n, std::exp(-2.0) + 0.006);
    EXPECT_GT(double(above2) / n, std::exp(-2.0) - 0.01);
    const double sharper = 3 * std::log(2.0) - std::log(4.0 / 3.0 * M_PI);
    EXPECT_NEAR(seedEvidenceCube(0.05, 0.35, 3, 0.0) - seedEvidence(0.05, 0.35, 3, 0.0), sharper,
                1e-12);
    EXPECT_EQ(seedEvidenceCube(0.6, 0.35, 3, 0.0), 0.0);
}
