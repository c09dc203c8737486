#include "scan_folder.hpp"

#include <pcl/PCLPointCloud2.h>
#include <pcl/io/pcd_io.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <stdexcept>

namespace forestslam::apps {
namespace {

namespace fs = std::filesystem;

bool numericStem(const fs::path &p, double &value) {
    const std::string s = p.stem().string();
    if (s.empty()) return false;
    char *end = nullptr;
    value = std::strtod(s.c_str(), &end);
    return end == s.c_str() + s.size() && std::isfinite(value);
}

double fieldValue(const std::uint8_t *p, std::uint8_t type) {
    switch (type) {
        case pcl::PCLPointField::INT8:
            return *reinterpret_cast<const std::int8_t *>(p);
        case pcl::PCLPointField::UINT8:
            return *p;
        case pcl::PCLPointField::INT16: {
            std::int16_t v;
            std::memcpy(&v, p, 2);
            return v;
        }
        case pcl::PCLPointField::UINT16: {
            std::uint16_t v;
            std::memcpy(&v, p, 2);
            return v;
        }
        case pcl::PCLPointField::INT32: {
            std::int32_t v;
            std::memcpy(&v, p, 4);
            return v;
        }
        case pcl::PCLPointField::UINT32: {
            std::uint32_t v;
            std::memcpy(&v, p, 4);
            return v;
        }
        case pcl::PCLPointField::FLOAT32: {
            float v;
            std::memcpy(&v, p, 4);
            return v;
        }
        case pcl::PCLPointField::FLOAT64: {
            double v;
            std::memcpy(&v, p, 8);
            return v;
        }
        default:
            return std::numeric_limits<double>::quiet_NaN();
    }
}

const pcl::PCLPointField *findField(const pcl::PCLPointCloud2 &cloud, const std::string &name) {
    for (const auto &f : cloud.fields)
        if (f.name == name) return &f;
    return nullptr;
}

Eigen::VectorXd column(const pcl::PCLPointCloud2 &cloud, const pcl::PCLPointField &f) {
    const Eigen::Index n = static_cast<Eigen::Index>(cloud.width) * cloud.height;
    Eigen::VectorXd out(n);
    for (Eigen::Index i = 0; i < n; ++i)
        out(i) = fieldValue(&cloud.data[i * cloud.point_step + f.offset], f.datatype);
    return out;
}

odometry::LidarScan readPcd(const std::string &path) {
    // The header first: PCL's reader crashes on a file without one (a text file named .pcd).
    pcl::PCDReader reader;
    pcl::PCLPointCloud2 cloud;
    Eigen::Vector4f origin;
    Eigen::Quaternionf orientation;
    int version = 0, binary = 0;
    unsigned int data_start = 0;
    if (reader.readHeader(path, cloud, origin, orientation, version, binary, data_start) < 0 ||
        cloud.fields.empty() || std::size_t(cloud.width) * cloud.height == 0)
        throw std::runtime_error(path + ": not a PCD file with points (no valid header)");
    if (reader.read(path, cloud) < 0) throw std::runtime_error(path + ": unreadable PCD");
    const auto *x = findField(cloud, "x"), *y = findField(cloud, "y"), *z = findField(cloud, "z");
    if (!x || !y || !z) throw std::runtime_error(path + ": PCD without fields x y z");
    odometry::LidarScan scan;
    const Eigen::VectorXd cx = column(cloud, *x), cy = column(cloud, *y), cz = column(cloud, *z);
    scan.points.resize(cx.size(), 3);
    scan.points << cx, cy, cz;
    if (const auto *f = findField(cloud, "intensity")) scan.intensity = column(cloud, *f);
    if (const auto *f = findField(cloud, "ring")) scan.ring = column(cloud, *f).cast<int>();
    if (const auto *f = findField(cloud, "time")) scan.time = column(cloud, *f);
    return scan;
}

odometry::LidarScan readKittiBin(const std::string &path) {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw std::runtime_error(path + ": cannot open");
    std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (bytes.size() % 16 != 0)
        throw std::runtime_error(path + ": " + std::to_string(bytes.size()) +
                                 " bytes, not a multiple of 16 (KITTI float32 x y z intensity)");
    const Eigen::Index n = static_cast<Eigen::Index>(bytes.size() / 16);
    Eigen::Map<const Eigen::Matrix<float, Eigen::Dynamic, 4, Eigen::RowMajor>> raw(
        reinterpret_cast<const float *>(bytes.data()), n, 4);
    odometry::LidarScan scan;
    scan.points = raw.leftCols<3>().cast<double>();
    scan.intensity = raw.col(3).cast<double>();
    return scan;
}

}  // namespace

std::vector<ScanFile> listScans(const std::string &folder, double rate_hz) {
    std::error_code ec;
    if (!fs::is_directory(folder, ec))
        throw std::invalid_argument(folder + ": not a folder of scans");
    std::vector<fs::path> files;
    bool pcd = false, bin = false;
    for (const auto &entry : fs::directory_iterator(folder, ec)) {
        const auto ext = entry.path().extension();
        if (!entry.is_regular_file() || (ext != ".pcd" && ext != ".bin")) continue;
        (ext == ".pcd" ? pcd : bin) = true;
        files.push_back(entry.path());
    }
    if (ec) throw std::invalid_argument(folder + ": cannot list (" + ec.message() + ")");
    if (files.empty()) throw std::invalid_argument(folder + ": no .pcd or .bin scan files");
    if (pcd && bin) throw std::invalid_argument(folder + ": mixes .pcd and .bin files");
    std::vector<ScanFile> scans;
    bool numeric = true;
    for (const auto &f : files) {
        double t = 0;
        numeric = numeric && numericStem(f, t);
        scans.push_back({f.string(), t});
    }
    if (numeric) {
        std::sort(scans.begin(), scans.end(),
                  [](const ScanFile &a, const ScanFile &b) { return a.stamp < b.stamp; });
        return scans;
    }
    std::sort(scans.begin(), scans.end(),
              [](const ScanFile &a, const ScanFile &b) { return a.path < b.path; });
    for (std::size_t i = 0; i < scans.size(); ++i) scans[i].stamp = double(i) / rate_hz;
    return scans;
}

odometry::LidarScan readScan(const ScanFile &file) {
    odometry::LidarScan scan =
        fs::path(file.path).extension() == ".bin" ? readKittiBin(file.path) : readPcd(file.path);
    scan.stamp = file.stamp;
    return scan;
}

}  // namespace forestslam::apps
