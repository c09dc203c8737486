// forestslam_odometry SCANS_DIR --sensor NAME|profile.yaml --out trajectory.tum
// Tree odometry over a folder of PCD or KITTI .bin scans, without Python: the poses of the
// sensor (TUM: stamp tx ty tz qx qy qz qw, the first scan's frame) and a summary on stderr.
#include <time.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

#include "forestslam/odometry/sensor_profile.hpp"
#include "forestslam/odometry/tree_odometry.hpp"
#include "scan_folder.hpp"

namespace fs = std::filesystem;
using namespace forestslam;

namespace {

const char *kUsage =
    "usage: forestslam_odometry SCANS_DIR --sensor NAME|profile.yaml --out trajectory.tum\n"
    "  SCANS_DIR  a folder of .pcd (x y z, optional intensity ring time) or KITTI .bin scans;\n"
    "             numeric file names are stamps in seconds, else the file order at the\n"
    "             profile's rate\n"
    "  --sensor   a shipped sensor profile (vlp16, hdl32, os1-64, rs-m1, ...) or a YAML file\n"
    "  --out      the trajectory to write (TUM format)\n";

struct Arguments {
    std::string scans, sensor, out;
};

Arguments parseArguments(int argc, char **argv) {
    Arguments a;
    for (int i = 1; i < argc; ++i) {
        const std::string arg = argv[i];
        if (arg == "-h" || arg == "--help") {
            std::cout << kUsage;
            std::exit(0);
        }
        if ((arg == "--sensor" || arg == "--out") && i + 1 < argc)
            (arg == "--sensor" ? a.sensor : a.out) = argv[++i];
        else if (!arg.empty() && arg[0] != '-' && a.scans.empty())
            a.scans = arg;
        else
            throw std::invalid_argument("unexpected argument '" + arg + "'");
    }
    if (a.scans.empty() || a.sensor.empty() || a.out.empty())
        throw std::invalid_argument("SCANS_DIR, --sensor and --out are required");
    return a;
}

// Shipped profiles: installed beside the program (<prefix>/share/forestslam/sensors), or the
// source tree's when run from a build folder.
std::vector<std::string> profileFolders() {
    std::vector<std::string> folders;
    std::error_code ec;
    const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
    if (!ec)
        folders.push_back((exe.parent_path().parent_path() / "share/forestslam/sensors").string());
    folders.push_back(FORESTSLAM_SOURCE_PROFILES);
    return folders;
}

double processCpuSeconds() {
    timespec ts{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

// Per-point time must be seconds within a few sweeps of the stamp; anything else is ignored
// (no deskew) rather than trusted.
bool plausibleTimes(const Eigen::VectorXd &t, double rate_hz) {
    const double limit = 3.0 / rate_hz;
    for (Eigen::Index i = 0; i < t.size(); ++i)
        if (std::isfinite(t(i)) && std::abs(t(i)) > limit) return false;
    return true;
}

void writeTumLine(std::ostream &out, const odometry::OdometryResult &r) {
    const Eigen::Vector3d t = r.T_world_sensor.translation();
    const Eigen::Quaterniond q(r.T_world_sensor.rotation());
    out << std::fixed << std::setprecision(6) << r.stamp << ' ' << std::setprecision(6) << t.x()
        << ' ' << t.y() << ' ' << t.z() << ' ' << std::setprecision(9) << q.x() << ' ' << q.y()
        << ' ' << q.z() << ' ' << q.w() << '\n';
}

int run(const Arguments &args) {
    const odometry::SensorProfile profile =
        odometry::findSensorProfile(args.sensor, profileFolders());
    const auto files = apps::listScans(args.scans, profile.rate_hz);
    perception::PerceptionConfig perception;
    perception.intensity_threshold = profile.sensor.intensity_threshold;
    odometry::TreeOdometry odometry(profile.sensor, {}, perception);
    std::ofstream out(args.out);
    if (!out) throw std::runtime_error(args.out + ": cannot write");
    int degraded = 0, restarts = 0, skipped = 0, ignored_times = 0;
    const double cpu0 = processCpuSeconds();
    for (const auto &file : files) {
        odometry::LidarScan scan;
        try {
            scan = apps::readScan(file);
        } catch (const std::exception &e) {
            std::cerr << "warning: " << e.what() << "; scan skipped\n";
            ++skipped;
            continue;
        }
        if (scan.time.size() && !plausibleTimes(scan.time, profile.rate_hz)) {
            scan.time.resize(0);
            ++ignored_times;
        }
        const odometry::OdometryResult r = odometry.registerScan(scan);
        if (r.stamp_check.restarted) {
            std::cerr << "warning: " << file.path << ": " << r.stamp_check.gap_s
                      << " s since the previous scan; the motion model restarts\n";
            ++restarts;
        }
        degraded += r.degraded;
        writeTumLine(out, r);
        out.flush();  // whole lines on disk as we go: a killed run leaves a valid trajectory
    }
    const double cpu = processCpuSeconds() - cpu0;
    const int n = odometry.scans();
    std::cerr << n << " scans -> " << args.out << "; " << degraded << " degraded, " << restarts
              << " motion restarts, " << skipped << " unreadable, " << ignored_times
              << " with implausible per-point time (not deskewed); " << std::setprecision(3) << cpu
              << " CPU s, " << (cpu > 0 ? n / cpu : 0.0) << " scans per CPU second\n";
    if (n == 0) std::cerr << "forestslam_odometry: " << args.scans << ": no readable scan\n";
    return n > 0 ? 0 : 1;
}

}  // namespace

int main(int argc, char **argv) {
    try {
        return run(parseArguments(argc, argv));
    } catch (const std::exception &e) {
        std::cerr << "forestslam_odometry: " << e.what() << "\n";
        if (argc < 2) std::cerr << kUsage;
        return 2;
    }
}
