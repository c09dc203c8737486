// Sensor profiles (python/forestslam/sensors/profiles/*.yaml, installed with the C++ package
// under share/forestslam/sensors): what the odometry and perception need to know of a LiDAR.
#pragma once

#include <string>
#include <vector>

#include "forestslam/odometry/tree_odometry.hpp"

namespace forestslam::odometry {

struct SensorProfile {
    std::string name;
    OdometrySensor sensor;  // kind, range-image geometry, intensity threshold
    double rate_hz = 10.0;  // sweeps per second
};

// A profile YAML file. Throws std::invalid_argument naming the file and the key on a missing,
// unknown or ill-typed key or an out-of-range value.
SensorProfile loadSensorProfile(const std::string &path);

// A shipped profile by name (searched in `folders`, in order) or a YAML file path.
SensorProfile findSensorProfile(const std::string &name_or_path,
                                const std::vector<std::string> &folders);

}  // namespace forestslam::odometry
