#include "forestslam/registration/deskew.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

namespace forestslam::registration {

Points3 deskewPoints(const Eigen::Ref<const Points3> &points,
                     const Eigen::Ref<const Eigen::VectorXd> &times, const Vector6d &twist_per_s) {
    if (times.size() != points.rows())
        throw std::invalid_argument("deskewPoints: " + std::to_string(times.size()) +
                                    " times for " + std::to_string(points.rows()) + " points");
    Points3 out = points;
    const Eigen::Vector3d v = twist_per_s.head<3>();
    const Eigen::Vector3d w = twist_per_s.tail<3>();
    const double speed = w.norm();
    const Eigen::Vector3d k = speed > 1e-12 ? Eigen::Vector3d(w / speed) : Eigen::Vector3d::Zero();
    // Drivers that stamp a firing once give its returns one time (about 9 per time in the
    // simulated VLP-16 scans): the rotation's cos and sin once per run of equal times.
    double t_last = std::numeric_limits<double>::quiet_NaN(), c = 1.0, s = 0.0;
    for (Eigen::Index i = 0; i < points.rows(); ++i) {
        const double t = times(i);
        if (!std::isfinite(t)) continue;
        const Eigen::Vector3d p = points.row(i).transpose();
        Eigen::Vector3d q = p;
        if (speed > 1e-12) {
            if (t != t_last) {
                const double theta = t * speed;
                c = std::cos(theta), s = std::sin(theta), t_last = t;
            }
            q = p * c + k.cross(p) * s + k * (k.dot(p) * (1.0 - c));
        }
        out.row(i) = (q + t * v).transpose();
    }
    return out;
}

}  // namespace forestslam::registration
