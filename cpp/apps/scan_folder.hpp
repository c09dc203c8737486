// A folder of LiDAR scans for the forestslam_odometry program: PCD files (fields x y z, and
// intensity, ring, time when present) or KITTI .bin files (float32 x y z intensity), one scan
// per file. Stamps from numeric file names (seconds), else from the file order at a rate.
#pragma once

#include <string>
#include <vector>

#include "forestslam/odometry/tree_odometry.hpp"

namespace forestslam::apps {

struct ScanFile {
    std::string path;
    double stamp = 0.0;
};

// The scan files of `folder` in time order with their stamps. Throws std::invalid_argument when
// the folder is missing or holds no .pcd / .bin file, or when it mixes both.
std::vector<ScanFile> listScans(const std::string &folder, double rate_hz);

// One scan. Throws std::runtime_error naming the file when it cannot be read.
odometry::LidarScan readScan(const ScanFile &file);

}  // namespace forestslam::apps
