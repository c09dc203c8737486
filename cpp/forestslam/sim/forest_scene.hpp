// The simulated forest: heightfield terrain plus analytic primitives in a uniform XY grid, and a
// batch ray caster returning the first hit of each ray (physically correct occlusion).
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "forestslam/common/types.hpp"
#include "forestslam/sim/ray_primitives.hpp"

namespace forestslam::sim {

// Visits the cells of a uniform 2D grid crossed by the ray's XY projection for t in [t0, t1], in
// order; visit(ix, iy, t_enter, t_exit) returns false to stop.
template <class Visit>
void traverseGrid(double x0, double y0, double cell, int nx, int ny, const Ray &ray, double t0,
                  double t1, Visit &&visit);

// The XY part of a ray with its reciprocals (0 where the ray is parallel to that axis), computed
// once per ray for all the grids it walks.
struct GridRay {
    explicit GridRay(const Ray &ray);
    double ox, oy, dx, dy, inv_dx, inv_dy;
};
template <class Visit>
void traverseGrid(double x0, double y0, double cell, double inv_cell, int nx, int ny,
                  const GridRay &r, double t0, double t1, Visit &&visit);

// Terrain heights on a regular vertex grid; each cell is split into two triangles along its
// (0,0)-(1,1) diagonal, so heights are piecewise linear and rays hit it exactly.
class Heightfield {
  public:
    Heightfield() = default;
    // z: (ny+1, nx+1) vertex heights, row iy at y = y0 + iy * cell, column ix at x = x0 + ix *
    // cell.
    Heightfield(double x0, double y0, double cell, const Eigen::MatrixXd &z);

    bool empty() const { return nx_ == 0; }
    // Height of the triangulated surface at (x, y); NaN outside the grid.
    double heightAt(double x, double y) const;
    bool intersect(const Ray &ray, double t_max, Hit &hit) const;
    bool intersect(const Ray &ray, const GridRay &grid_ray, double t_max, Hit &hit) const;

  private:
    double vertex(int ix, int iy) const { return z_[static_cast<size_t>(iy) * (nx_ + 1) + ix]; }
    bool intersectCell(int ix, int iy, const Ray &ray, double t0, double t1, Hit &hit) const;

    double x0_ = 0, y0_ = 0, cell_ = 1, inv_cell_ = 1;
    int nx_ = 0, ny_ = 0;  // cells
    std::vector<double> z_;
    // Coarse blocks of kBlock x kBlock cells with their min/max height, to skip empty air fast.
    static constexpr int kBlock = 8;
    int nbx_ = 0, nby_ = 0;
    std::vector<double> block_min_, block_max_;
    double z_max_ = -kInf;
};

struct CastResult {
    Eigen::VectorXd range;  // NaN where no return
    Eigen::Matrix<uint8_t, Eigen::Dynamic, 1> surface;
    Eigen::Matrix<int32_t, Eigen::Dynamic, 1> object;
    Eigen::VectorXd cos_incidence;
};

class ForestScene {
  public:
    ForestScene(Heightfield terrain, std::vector<Stem> stems, std::vector<Cylinder> cylinders,
                std::vector<FoliageEllipsoid> foliage, double cell_m = 3.0);

    Hit cast(const Ray &ray) const;
    // One ray per row of dirs (N,3, unit); origins (G,3) with G dividing N: ray i starts at
    // origin i / (N/G) (G = 1: one shared origin, G = N: one each). Returns are kept in
    // [range_min, range_max]. seed makes foliage penetration reproducible: ray i uses key (seed,
    // i).
    CastResult castRays(const Eigen::Ref<const Points3> &origins,
                        const Eigen::Ref<const Points3> &dirs, double range_min, double range_max,
                        uint64_t seed) const;

    // First hits of rays[0..n): hits[i] is exactly cast(rays[i]). Consecutive rays with origins
    // within 1 cm of each other whose XY directions lie in a narrow fan (successive firing
    // columns of a spinning sensor, a few neighbours in a raster row) are cast together: one
    // walk over the grid columns covering all their XY paths, each primitive of the covered
    // cells rejected once for the whole bundle, then per ray only where its slopes reach the
    // primitive's box, and the exact test. Steep rays, wide fans and lone rays are cast one by
    // one.
    void castBatch(const Ray *rays, size_t n, Hit *hits) const;

    const Heightfield &terrain() const { return terrain_; }
    const std::vector<Stem> &stems() const { return stems_; }

  private:
    // Construction stages (forest_scene.cpp): each primitive's bounding box (and the constants
    // of its exact test), the grid framing all the boxes, and the bins listing them.
    struct Box;
    struct CellRange;
    struct Prim;
    std::vector<Box> boundPrimitives();
    void frameGrid(const std::vector<Box> &boxes);
    CellRange cellRange(const Box &b) const;
    template <class Visit>
    void forEachCell(const Box &b, Visit &&visit) const;
    void binPrimitives(const std::vector<Box> &boxes);
    Prim compactPrim(const Box &b) const;

    bool testPrimitive(uint32_t code, const Ray &ray, double t_max, Hit &hit) const;
    // cast()'s test of one grid cell: the primitives of its layers l0..l1 whose boxes the ray's
    // segment [t, t_hi] meets, each once per ray, into best.
    struct RecentRows;
    void testCell(const Ray &ray, size_t c, int l0, int l1, double t, double t_hi, Hit &best,
                  RecentRows &tested) const;
    // The terrain hit (into best), then the part [t, t1] of the ray left to walk through the
    // primitive grid: before that hit, below the highest primitive, inside the grid's XY slab.
    // False when nothing is left. Shared by cast() and castBundle() so both see the same rays.
    bool startCast(const Ray &ray, const GridRay &grid_ray, Hit &best, double &t, double &t1) const;
    // n (2..kMaxBundle) rays with nearby origins, their XY directions within 60 degrees of the
    // x axis (along_x) or of the y axis, all pointing the same way along it. stamp (one per row
    // of prims_) marks with `id` the primitives already tested for this bundle.
    static constexpr int kMaxBundle = 128;
    void castBundle(const Ray *rays, int n, bool along_x, Hit *hits, uint32_t *stamp,
                    uint32_t id) const;
    // The stages of castBundle, on the walk's state (defined in forest_scene.cpp): the lanes of
    // the rays that reach the grid, one grid column of the walk, one primitive against the lanes.
    struct BundleWalk;
    void startBundle(BundleWalk &w, int n, bool along_x) const;
    void walkColumn(BundleWalk &w, bool along_x, int iu, double a0, double a1e, uint32_t *stamp,
                    uint32_t id) const;
    void testLanes(BundleWalk &w, const Prim &p) const;

    Heightfield terrain_;
    std::vector<Stem> stems_;
    std::vector<Cylinder> cylinders_;
    std::vector<FoliageEllipsoid> foliage_;
    double x0_ = 0, y0_ = 0, cell_ = 2.0, inv_cell_ = 0.5;
    int nx_ = 0, ny_ = 0;
    // One compact record per primitive: its code (type in the top bits, row below) and its 3D
    // bounding box in float, relative to (x0_, y0_, z0_) and rounded outwards, so the rejection
    // stays conservative. Bins hold 4-byte rows of prims_: the bin lists of a whole stand stay in
    // cache, and a primitive's box is shared by all the bins it lies in.
    struct Prim {
        float lo[3], hi[3];
        uint32_t code;
        uint32_t pad;
    };
    std::vector<Prim> prims_;
    std::vector<StemCoeffs> stem_coeffs_;  // per-primitive constants of the exact tests
    std::vector<CylinderCoeffs> cylinder_coeffs_;
    std::vector<FoliageCoeffs> foliage_coeffs_;
    // Bins = XY cell x vertical layer (1 m, coarser for stands over 64 m tall), so rays below the
    // crowns never look at foliage.
    static constexpr double kLayerM = 1.0;
    static constexpr int kMaxLayers = 64;
    int layerOf(double z) const {
        const double l = std::clamp((z - z0_) * inv_layer_m_, 0.0, nl_ - 1.0);
        return static_cast<int>(l);
    }
    double z0_ = 0, layer_m_ = 1.0, inv_layer_m_ = 1.0;
    int nl_ = 1;
    std::vector<uint32_t> bin_start_;  // CSR: bin b holds bin_items_[start[b], start[b+1])
    std::vector<uint32_t> bin_items_;  // rows of prims_
    // Per XY cell, bit l set when layer l holds an item: empty bins are skipped without
    // touching the bin lists.
    std::vector<uint64_t> cell_layers_;
    // Per XY cell, its primitives once each whatever their layers (CSR like the bins): a bundle
    // of rays (castBatch) spans many layers at once.
    std::vector<uint32_t> cell_start_, cell_items_;
    double z_max_ = -kInf;
};

}  // namespace forestslam::sim

#include "forestslam/sim/grid_traversal.ipp"
