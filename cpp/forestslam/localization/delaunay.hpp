// 2D Delaunay triangulation of trunk positions (incremental insertion with Lawson flips).
#pragma once

#include <array>
#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam::localization {

// Triangles are counter-clockwise and index the rows of the input. neighbours[t][i] is the
// triangle across the edge opposite triangles[t][i], or -1 on the convex hull.
struct Triangulation {
    std::vector<std::array<int, 3>> triangles;
    std::vector<std::array<int, 3>> neighbours;
    // Input rows that took part (finite and not a duplicate of an earlier row).
    std::vector<int> used_points;

    size_t size() const { return triangles.size(); }
    bool interior(int t) const {
        const auto &n = neighbours[t];
        return n[0] >= 0 && n[1] >= 0 && n[2] >= 0;
    }
};

// Delaunay triangulation of xy (N,2). Non-finite rows are ignored and rows closer than
// duplicate_tolerance (same units as xy) to an earlier row are skipped. Fewer than three
// usable points or all points collinear give an empty triangulation. Expected O(N log N).
Triangulation delaunayTriangulation(const Eigen::Ref<const Points2> &xy,
                                    double duplicate_tolerance = 1e-6);

// Orientation predicate: > 0 when a, b, c turn counter-clockwise (the side test).
double orient2d(const Eigen::Vector2d &a, const Eigen::Vector2d &b, const Eigen::Vector2d &c);

// > 0 when d lies strictly inside the circumcircle of the counter-clockwise triangle a, b, c.
double inCircle(const Eigen::Vector2d &a, const Eigen::Vector2d &b, const Eigen::Vector2d &c,
                const Eigen::Vector2d &d);

}  // namespace forestslam::localization
