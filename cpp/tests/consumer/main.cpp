// Links every concern through the umbrella header; runs the odometry on two tiny scans.
#include <forestslam/forestslam.hpp>
#include <iostream>

int main() {
    using namespace forestslam;
    odometry::TreeOdometry odometry(odometry::OdometrySensor{});
    odometry::LidarScan scan;
    scan.points = Points3::Random(100, 3) * 10.0;
    odometry.registerScan(scan);
    scan.stamp = 0.1;
    const auto result = odometry.registerScan(scan);
    std::cout << "consumer: " << odometry.scans() << " scans, method " << result.method << "\n";
    return odometry.scans() == 2 ? 0 : 1;
}
