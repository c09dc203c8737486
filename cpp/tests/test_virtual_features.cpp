#include <gtest/gtest.h>

#include <stdexcept>

#include "forestslam/features/virtual_features.hpp"
#include "tls_scene.hpp"

using namespace forestslam;

namespace {

// For each true stem within max_range of the origin, the nearest extracted stem.
void expectStems(const features::VirtualFeatures &vf, const test::Scene &scene,
                 const Pose3 &T_world_frame, double max_range, double tol_centre, double tol_radius,
                 int min_found) {
    int found = 0;
    for (const auto &st : scene.stems) {
        const Eigen::Vector3d c = T_world_frame.inverse() * Eigen::Vector3d(st.x, st.y, 0.0);
        if (c.head<2>().norm() > max_range) continue;
        double best = 1e9;
        Eigen::Index arg = -1;
        for (Eigen::Index s = 0; s < vf.stems.rows(); ++s) {
            const double d = (vf.stems.row(s).head<2>().transpose() - c.head<2>()).norm();
            if (d < best) best = d, arg = s;
        }
        if (arg < 0 || best > 0.5) continue;
        ++found;
        EXPECT_LT(best, tol_centre) << "stem at " << st.x << "," << st.y;
        EXPECT_NEAR(vf.stem_radii[arg], st.radius, tol_radius);
    }
    EXPECT_GE(found, min_found);
    // Every centre belongs to a true stem (no ground or boulder false positives).
    for (Eigen::Index i = 0; i < vf.centres.rows(); ++i) {
        const Eigen::Vector3d w = T_world_frame * vf.centres.row(i).transpose();
        double best = 1e9;
        for (const auto &st : scene.stems) {
            best = std::min(best, std::hypot(w.x() - st.x, w.y() - st.y));
        }
        EXPECT_LT(best, 0.1);
    }
}

}  // namespace

TEST(VirtualFeatures, RingsFindKnownStemCentres) {
    const auto scene = test::defaultScene();
    std::vector<std::uint16_t> rings;
    const Pose3 T = test::makePose(0.3, -0.2, 0.0, 0.0, 0.0, 0.4);
    const Points3 scan = test::raycast(scene, T, rings, 16, 0.2, 40.0, 0.005);
    const features::VirtualFeatures vf = features::extractVirtualFeaturesRings(scan, rings);
    ASSERT_EQ(vf.radii.size(), vf.centres.rows());
    ASSERT_EQ(vf.stem_ids.size(), vf.centres.rows());
    expectStems(vf, scene, T, 8.0, 0.03, 0.03, 5);
}

TEST(VirtualFeatures, LayersFindKnownStemCentres) {
    const auto scene = test::defaultScene();
    const Points3 map = test::denseMap(scene, 12.0, 0.03);
    const features::VirtualFeatures vf = features::extractVirtualFeaturesLayers(map);
    expectStems(vf, scene, Pose3::Identity(), 12.0, 0.01, 0.01, 7);
    EXPECT_EQ(vf.stems.rows(), 7);
}

TEST(VirtualFeatures, NoStemsAndBadInputs) {
    const auto scene = test::defaultScene(false);
    std::vector<std::uint16_t> rings;
    const Points3 scan = test::raycast(scene, Pose3::Identity(), rings);
    EXPECT_EQ(features::extractVirtualFeaturesRings(scan, rings).centres.rows(), 0);
    EXPECT_THROW(features::extractVirtualFeaturesRings(scan, {}),
                 std::invalid_argument);  // ring size
    EXPECT_EQ(features::extractVirtualFeaturesLayers(Points3(0, 3)).centres.rows(), 0);
}
