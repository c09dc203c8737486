#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>
#include <stdexcept>

#include "forestslam/odometry/sensor_profile.hpp"

using namespace forestslam::odometry;

TEST(SensorProfile, ShippedVlp16) {
    const SensorProfile p = findSensorProfile("vlp16", {FORESTSLAM_PROFILES});
    EXPECT_EQ(p.name, "vlp16");
    EXPECT_EQ(p.sensor.kind, "spinning");
    EXPECT_DOUBLE_EQ(p.rate_hz, 10.0);
    ASSERT_EQ(p.sensor.geometry.vertical_angles_rad.size(), 16u);
    EXPECT_NEAR(p.sensor.geometry.theta_v_rad, 2.0 * M_PI / 180, 1e-12);
    EXPECT_EQ(p.sensor.geometry.image_cols, 1800);
    EXPECT_DOUBLE_EQ(p.sensor.intensity_threshold, 100.0);
}

TEST(SensorProfile, ErrorsNameTheKey) {
    EXPECT_THROW(findSensorProfile("nosuch", {FORESTSLAM_PROFILES}), std::invalid_argument);
    const std::string path = testing::TempDir() + "bad_profile.yaml";
    std::ofstream(path)
        << "name: x\nkind: spinning\nchannels: sixteen\nvertical_fov_deg: [-15, 15]\n"
           "horizontal_fov_deg: 360\nazimuth_resolution_deg: 0.2\nrate_hz: 10\n"
           "range_min_m: 0.5\nrange_max_m: 100\nrange_noise_m: 0.01\n"
           "dropout_rate: 0\nimage_rows: 16\nimage_cols: 1800\n"
           "intensity_threshold: null\n";
    try {
        loadSensorProfile(path);
        FAIL() << "no error";
    } catch (const std::invalid_argument &e) {
        EXPECT_NE(std::string(e.what()).find("channels"), std::string::npos) << e.what();
    }
    std::ofstream(path) << "name: x\nbanana: 1\n";
    EXPECT_THROW(loadSensorProfile(path), std::invalid_argument);
    std::remove(path.c_str());
}
