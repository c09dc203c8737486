// Triangle descriptors and triangle-star features (Li et al.): a Delaunay triangle together with
// its three neighbours, described by area and squared perimeter in a rotation-invariant order.
#pragma once

#include <array>
#include <vector>

#include "forestslam/common/types.hpp"
#include "forestslam/localization/delaunay.hpp"

namespace forestslam::localization {

using StarFeature = Eigen::Matrix<double, 8, 1>;  // [A0, l0, A1, l1, A2, l2, A3, l3]
using StarFeatures = Eigen::Matrix<double, Eigen::Dynamic, 8, Eigen::RowMajor>;

// Area A and squared perimeter l of the triangle a, b, c.
Eigen::Vector2d triangleDescriptor(const Eigen::Vector2d &a, const Eigen::Vector2d &b,
                                   const Eigen::Vector2d &c);

// One star with a chosen starting edge. vertices: v0, v1, v2 of the centre triangle
// (counter-clockwise, edge v0-v1 first), then the apexes of the neighbours across the edges
// v0-v1, v1-v2, v2-v0. feature: the centre's (A, l), then the neighbours' in that order.
struct Star {
    int centre = -1;
    std::array<int, 6> vertices{};
    StarFeature feature = StarFeature::Zero();
};

// All stars of a triangulation: one per interior triangle (three neighbours), each in its
// canonical rotation (shortest centre edge first).
struct StarSet {
    Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor> descriptors;  // per triangle [A, l]
    std::vector<Star> stars;
    StarFeatures features() const;
};

// Index (0..2) of the shortest edge (triangles[t][k], triangles[t][k+1]) of triangle t.
int shortestEdge(const Triangulation &tri, const Eigen::Ref<const Points2> &xy, int t);

// Length of edge k of triangle t.
double edgeLength(const Triangulation &tri, const Eigen::Ref<const Points2> &xy, int t, int k);

// The star of interior triangle t starting at edge `rotation` (0..2); false if t is peripheral.
bool makeStar(
    const Triangulation &tri, const Eigen::Ref<const Points2> &xy,
    const Eigen::Ref<const Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>> &descriptors,
    int t, int rotation, Star &star);

StarSet buildStars(const Triangulation &tri, const Eigen::Ref<const Points2> &xy);

// Triangles (i, j, l) of every point i with two of its k nearest neighbours (edges at most
// max_edge), deduplicated, plus nothing else: unlike Delaunay triangles they survive a missed
// or an extra trunk nearby. Each is counter-clockwise with its shortest edge v0-v1 first.
// Only the rows in `rows` take part (all rows when empty).
std::vector<std::array<int, 3>> neighbourTriangles(const Eigen::Ref<const Points2> &xy,
                                                   const std::vector<int> &rows, int k,
                                                   double max_edge);

// Counter-clockwise order of a, b, c rotated so that edge v0-v1 is the shortest; false when
// the three points are (nearly) collinear.
bool canonicalTriangle(const Eigen::Ref<const Points2> &xy, std::array<int, 3> &tri);

// Side lengths |v0v1|, |v1v2|, |v2v0| of a triangle rotated to start at vertex `rotation`.
Eigen::Vector3d triangleSides(const Eigen::Ref<const Points2> &xy, const std::array<int, 3> &tri,
                              int rotation = 0);

// Search-space form of a feature, in metres: [sqrt(A_i), sqrt(l_i)] per triangle, so that
// trunk position noise moves every coordinate by a comparable amount.
StarFeature embedFeature(const StarFeature &feature);

}  // namespace forestslam::localization
