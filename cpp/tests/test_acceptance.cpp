#include <gtest/gtest.h>

#include <cmath>

#include "forestslam/localization/acceptance.hpp"

using forestslam::Points2;

TEST(Acceptance, PoissonTailKnownValues) {
    // P(X >= 1) = 1 - e^-mu; P(X >= 2) = 1 - e^-mu (1 + mu).
    EXPECT_NEAR(forestslam::poissonTailLog10(0.5, 1), -std::log10(1 - std::exp(-0.5)), 1e-12);
    EXPECT_NEAR(forestslam::poissonTailLog10(2.0, 2), -std::log10(1 - 3 * std::exp(-2.0)), 1e-12);
    EXPECT_EQ(forestslam::poissonTailLog10(2.0, 0), 0.0);
    // Far tail: P(X >= 30 | mu = 1) ~ e^-1 / 30! within a few percent.
    EXPECT_NEAR(forestslam::poissonTailLog10(1.0, 30), (1 + std::lgamma(31.0)) / std::log(10.0),
                0.02);
}

TEST(Acceptance, DensityOfAUniformGrid) {
    // One trunk per 2 m x 2 m: 0.25 per m^2 inside, less at the border, none far away.
    Points2 xy(50 * 50, 2);
    for (int i = 0; i < 50; ++i)
        for (int j = 0; j < 50; ++j) xy.row(i * 50 + j) << 2.0 * i + 1, 2.0 * j + 1;
    const forestslam::DensityGrid grid(xy);
    EXPECT_NEAR(grid.at(50, 50), 0.25, 1e-9);
    EXPECT_LT(grid.at(1, 1), 0.25);
    EXPECT_EQ(grid.at(500, 500), 0.0);
    EXPECT_NEAR(forestslam::chanceRate(0.25, 0.5), 1 - std::exp(-0.25 * M_PI * 0.25), 1e-12);
}

TEST(Acceptance, SeedsAndSearchAreDiscounted) {
    using forestslam::chanceEvidence;
    const auto base = chanceEvidence(14, 20, 1.0, 6, 1);
    EXPECT_NEAR(base.expected, 1.0 * 14 / 20, 1e-12);  // the 6 seed trunks carry no evidence
    EXPECT_NEAR(chanceEvidence(14, 20, 1.0, 6, 1000).significance, base.significance - 3, 1e-9);
    EXPECT_NEAR(chanceEvidence(6, 20, 1.0, 6, 1).significance, 0.0, 1e-12);
    EXPECT_GT(chanceEvidence(14, 20, 1.0, 3, 1).significance, base.significance);
}

TEST(Acceptance, JudgeGivesTheReason) {
    forestslam::AcceptanceConfig cfg;
    auto e = forestslam::chanceEvidence(20, 30, 0.5, 6, 10);
    EXPECT_TRUE(forestslam::judge(e, 0.3, cfg).accepted);
    EXPECT_NE(forestslam::judge(e, 0.9, cfg).reason.find("ambiguous"), std::string::npos);
    e = forestslam::chanceEvidence(9, 30, 6.0, 6, 10);  // a dense map explains 9 inliers
    EXPECT_NE(forestslam::judge(e, 0.0, cfg).reason.find("not significant"), std::string::npos);
    e = forestslam::chanceEvidence(5, 5, 0.0, 3, 1);
    EXPECT_EQ(forestslam::judge(e, 0.0, cfg).reason, "too few inliers");
}
