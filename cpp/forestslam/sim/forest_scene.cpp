#include "forestslam/sim/forest_scene.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace forestslam::sim {

namespace {
constexpr uint32_t kStemCode = 0u << 30, kCylinderCode = 1u << 30, kFoliageCode = 2u << 30;
constexpr uint32_t kIndexMask = (1u << 30) - 1;

// Nearest floats below / above v: float boxes that always contain the double ones.
float floatDown(double v) {
    const float f = static_cast<float>(v);
    return static_cast<double>(f) > v ? std::nextafter(f, -std::numeric_limits<float>::infinity())
                                      : f;
}
float floatUp(double v) {
    const float f = static_cast<float>(v);
    return static_cast<double>(f) < v ? std::nextafter(f, std::numeric_limits<float>::infinity())
                                      : f;
}
}  // namespace

Heightfield::Heightfield(double x0, double y0, double cell, const Eigen::MatrixXd &z)
    : x0_(x0), y0_(y0), cell_(cell), inv_cell_(1.0 / cell) {
    if (!(cell > 0.0)) throw std::invalid_argument("heightfield cell must be > 0");
    if (z.rows() < 2 || z.cols() < 2)
        throw std::invalid_argument("heightfield needs >= 2x2 vertices");
    if (!z.allFinite()) throw std::invalid_argument("heightfield heights must be finite");
    ny_ = static_cast<int>(z.rows()) - 1;
    nx_ = static_cast<int>(z.cols()) - 1;
    z_.resize(static_cast<size_t>(z.rows()) * z.cols());
    for (int iy = 0; iy <= ny_; ++iy)
        for (int ix = 0; ix <= nx_; ++ix) z_[static_cast<size_t>(iy) * (nx_ + 1) + ix] = z(iy, ix);
    nbx_ = (nx_ + kBlock - 1) / kBlock;
    nby_ = (ny_ + kBlock - 1) / kBlock;
    block_min_.assign(static_cast<size_t>(nbx_) * nby_, kInf);
    block_max_.assign(static_cast<size_t>(nbx_) * nby_, -kInf);
    for (int iy = 0; iy <= ny_; ++iy) {
        for (int ix = 0; ix <= nx_; ++ix) {
            const double v = vertex(ix, iy);
            z_max_ = std::max(z_max_, v);
            // A vertex belongs to every block whose cells touch it.
            for (int by = std::max(0, (iy - 1) / kBlock); by <= std::min(nby_ - 1, iy / kBlock);
                 ++by)
                for (int bx = std::max(0, (ix - 1) / kBlock); bx <= std::min(nbx_ - 1, ix / kBlock);
                     ++bx) {
                    const size_t b = static_cast<size_t>(by) * nbx_ + bx;
                    block_min_[b] = std::min(block_min_[b], v);
                    block_max_[b] = std::max(block_max_[b], v);
                }
        }
    }
}

double Heightfield::heightAt(double x, double y) const {
    if (empty()) return std::nan("");
    const double gx = (x - x0_) / cell_, gy = (y - y0_) / cell_;
    if (!(gx >= 0.0 && gy >= 0.0 && gx <= nx_ && gy <= ny_)) return std::nan("");
    const int ix = std::min(static_cast<int>(gx), nx_ - 1),
              iy = std::min(static_cast<int>(gy), ny_ - 1);
    const double fx = gx - ix, fy = gy - iy;
    const double z00 = vertex(ix, iy), z10 = vertex(ix + 1, iy), z01 = vertex(ix, iy + 1),
                 z11 = vertex(ix + 1, iy + 1);
    if (fx >= fy) return z00 + fx * (z10 - z00) + fy * (z11 - z10);
    return z00 + fy * (z01 - z00) + fx * (z11 - z01);
}

bool Heightfield::intersectCell(int ix, int iy, const Ray &ray, double t0, double t1,
                                Hit &hit) const {
    const double z00 = vertex(ix, iy), z10 = vertex(ix + 1, iy), z01 = vertex(ix, iy + 1),
                 z11 = vertex(ix + 1, iy + 1);
    const double oz = ray.origin.z(), dz = ray.dir.z();
    const double zr_lo = std::min(oz + t0 * dz, oz + t1 * dz);
    const double zr_hi = std::max(oz + t0 * dz, oz + t1 * dz);
    if (zr_lo > std::max(std::max(z00, z10), std::max(z01, z11)) + 1e-9) return false;
    if (zr_hi < std::min(std::min(z00, z10), std::min(z01, z11)) - 1e-9) {
        // Ray under the surface (should not happen): report the cell entry as the hit.
        hit.t = t0;
        hit.cos_incidence = 1.0;
        return true;
    }
    const double xc = x0_ + ix * cell_, yc = y0_ + iy * cell_;
    const double fx0 = (ray.origin.x() - xc) * inv_cell_, fdx = ray.dir.x() * inv_cell_;
    const double fy0 = (ray.origin.y() - yc) * inv_cell_, fdy = ray.dir.y() * inv_cell_;
    const double tol = 1e-9;
    double best = kInf, gbx = 0, gby = 0;
    // Triangle A (fx >= fy): z = z00 + fx (z10 - z00) + fy (z11 - z10); B (fy > fx) likewise.
    const double grads[2][2] = {{z10 - z00, z11 - z10}, {z11 - z01, z01 - z00}};
    for (int tri = 0; tri < 2; ++tri) {
        const double gx = grads[tri][0], gy = grads[tri][1];
        const double denom = dz - fdx * gx - fdy * gy;
        if (std::abs(denom) < 1e-15) continue;
        const double t = (z00 + fx0 * gx + fy0 * gy - oz) / denom;
        if (t < t0 - tol || t > t1 + tol || t < ray.t_min || t >= best) continue;
        const double fx = fx0 + t * fdx, fy = fy0 + t * fdy;
        if (fx < -tol || fx > 1 + tol || fy < -tol || fy > 1 + tol) continue;
        if (tri == 0 ? fx < fy - tol : fy < fx - tol) continue;
        best = t;
        gbx = gx;
        gby = gy;
    }
    if (best == kInf) return false;
    const Eigen::Vector3d n(-gbx * inv_cell_, -gby * inv_cell_, 1.0);
    hit.t = best;
    hit.cos_incidence = std::abs(ray.dir.dot(n)) / n.norm();
    return true;
}

bool Heightfield::intersect(const Ray &ray, double t_max, Hit &hit) const {
    return intersect(ray, GridRay(ray), t_max, hit);
}

bool Heightfield::intersect(const Ray &ray, const GridRay &grid_ray, double t_max, Hit &hit) const {
    if (empty()) return false;
    const double oz = ray.origin.z(), dz = ray.dir.z();
    if (dz >= 0.0 && oz > z_max_) return false;
    if (dz > 0.0) t_max = std::min(t_max, (z_max_ - oz) / dz + 1e-9);  // above all: no hit
    bool found = false;
    Hit local;
    const double block = cell_ * kBlock;
    traverseGrid(x0_, y0_, block, inv_cell_ / kBlock, nbx_, nby_, grid_ray, ray.t_min, t_max,
                 [&](int bx, int by, double tb0, double tb1) {
                     // Walk the cells only where the ray is below the block's highest vertex.
                     const double top = block_max_[static_cast<size_t>(by) * nbx_ + bx] + 1e-9;
                     double ta = tb0, tb = tb1;
                     if (dz < 0.0)
                         ta = std::max(ta, (top - oz) / dz);
                     else if (dz > 0.0)
                         tb = std::min(tb, (top - oz) / dz);
                     else if (oz > top)
                         return true;
                     if (ta > tb) return true;
                     traverseGrid(x0_, y0_, cell_, inv_cell_, nx_, ny_, grid_ray, ta, tb,
                                  [&](int ix, int iy, double t0, double t1) {
                                      if (intersectCell(ix, iy, ray, t0, t1, local)) {
                                          found = true;
                                          return false;
                                      }
                                      return true;
                                  });
                     return !found;
                 });
    if (!found) return false;
    hit = local;
    hit.surface = kGround;
    hit.object = -1;
    return true;
}

// The axis-aligned bounding box of one primitive, world frame, and its code in prims_.
struct ForestScene::Box {
    uint32_t code;
    double xmin, ymin, xmax, ymax, zmax, zmin;
};

// The grid cells [ix0, ix1] x [iy0, iy1] and layers [l0, l1] a box overlaps.
struct ForestScene::CellRange {
    int ix0, iy0, ix1, iy1, l0, l1;
};

namespace {

void checkStem(const Stem &s) {
    if (!(s.semi_a > 0 && s.semi_b > 0)) throw std::invalid_argument("stem semi-axes must be > 0");
    if (s.sides != 0 && s.sides < 3)
        throw std::invalid_argument("a polygonal stem needs at least 3 sides (0: smooth)");
    if (!(s.irregularity >= 0.0 && s.irregularity < 0.5 && s.flare_amp >= 0.0 &&
          s.flare_height > 0.0 && s.bark_amp >= 0.0))
        throw std::invalid_argument(
            "stem irregularity must be in [0, 0.5), flare and bark >= 0, flare height > 0");
}

// Largest horizontal distance of the stem's (segment's) surface from its axis: shape factor,
// taper and flare at their most, plus the bark in normalised units.
double stemReach(const Stem &s, const StemCoeffs &coeffs) {
    const double scale = std::max(s.radiusScale(s.h_bottom), s.radiusScale(s.height));
    const double eps = s.bark_amp / (0.5 * (s.semi_a + s.semi_b));
    return std::max(s.semi_a, s.semi_b) * (coeffs.q_max * (scale + s.flare(s.h_bottom)) + eps);
}

bool finiteBox(double xmin, double ymin, double xmax, double ymax, double zmax, double zmin) {
    return std::isfinite(xmin) && std::isfinite(xmax) && std::isfinite(ymin) &&
           std::isfinite(ymax) && std::isfinite(zmax) && std::isfinite(zmin);
}

}  // namespace

ForestScene::ForestScene(Heightfield terrain, std::vector<Stem> stems,
                         std::vector<Cylinder> cylinders, std::vector<FoliageEllipsoid> foliage,
                         double cell_m)
    : terrain_(std::move(terrain)),
      stems_(std::move(stems)),
      cylinders_(std::move(cylinders)),
      foliage_(std::move(foliage)),
      cell_(cell_m),
      inv_cell_(1.0 / cell_m) {
    if (!(cell_m > 0.0)) throw std::invalid_argument("scene grid cell must be > 0");
    if (stems_.size() > kIndexMask || cylinders_.size() > kIndexMask ||
        foliage_.size() > kIndexMask)
        throw std::invalid_argument("too many primitives");
    const std::vector<Box> boxes = boundPrimitives();
    if (boxes.empty()) return;
    frameGrid(boxes);
    binPrimitives(boxes);
}

std::vector<ForestScene::Box> ForestScene::boundPrimitives() {
    std::vector<Box> boxes;
    stem_coeffs_.reserve(stems_.size());
    for (size_t i = 0; i < stems_.size(); ++i) {
        const Stem &s = stems_[i];
        stem_coeffs_.emplace_back(s);
        checkStem(s);
        const double r = stemReach(s, stem_coeffs_.back());
        // The axis leans: its ends bound the box in XY.
        const double xa = s.base.x() + s.shear.x() * s.h_bottom,
                     xb = s.base.x() + s.shear.x() * s.height;
        const double ya = s.base.y() + s.shear.y() * s.h_bottom,
                     yb = s.base.y() + s.shear.y() * s.height;
        boxes.push_back({kStemCode | static_cast<uint32_t>(i), std::min(xa, xb) - r,
                         std::min(ya, yb) - r, std::max(xa, xb) + r, std::max(ya, yb) + r,
                         s.base.z() + s.height, s.base.z() + s.h_bottom});
    }
    for (size_t i = 0; i < cylinders_.size(); ++i) {
        const Cylinder &c = cylinders_[i];
        cylinder_coeffs_.emplace_back(c);
        const Eigen::Vector3d lo = c.p0.cwiseMin(c.p1).array() - c.radius;
        const Eigen::Vector3d hi = c.p0.cwiseMax(c.p1).array() + c.radius;
        boxes.push_back({kCylinderCode | static_cast<uint32_t>(i), lo.x(), lo.y(), hi.x(), hi.y(),
                         hi.z(), lo.z()});
    }
    for (size_t i = 0; i < foliage_.size(); ++i) {
        const FoliageEllipsoid &f = foliage_[i];
        foliage_coeffs_.emplace_back(f);
        if (!(f.radii.minCoeff() > 0 && f.sigma > 0))
            throw std::invalid_argument("foliage radii and sigma must be > 0");
        const Eigen::Vector3d lo = f.centre - f.radii, hi = f.centre + f.radii;
        boxes.push_back({kFoliageCode | static_cast<uint32_t>(i), lo.x(), lo.y(), hi.x(), hi.y(),
                         hi.z(), lo.z()});
    }
    return boxes;
}

void ForestScene::frameGrid(const std::vector<Box> &boxes) {
    double xmin = kInf, ymin = kInf, xmax = -kInf, ymax = -kInf, zmin = kInf;
    for (const Box &b : boxes) {
        if (!finiteBox(b.xmin, b.ymin, b.xmax, b.ymax, b.zmax, b.zmin))
            throw std::invalid_argument("primitive with non-finite coordinates");
        xmin = std::min(xmin, b.xmin);
        ymin = std::min(ymin, b.ymin);
        xmax = std::max(xmax, b.xmax);
        ymax = std::max(ymax, b.ymax);
        zmin = std::min(zmin, b.zmin);
        z_max_ = std::max(z_max_, b.zmax);
    }
    x0_ = xmin;
    y0_ = ymin;
    z0_ = zmin;
    nx_ = std::max(1, static_cast<int>(std::ceil((xmax - xmin) / cell_)));
    ny_ = std::max(1, static_cast<int>(std::ceil((ymax - ymin) / cell_)));
    nl_ = std::clamp(static_cast<int>(std::ceil((z_max_ - zmin) / kLayerM)), 1, kMaxLayers);
    layer_m_ = std::max((z_max_ - zmin) / nl_, 1e-3);
    inv_layer_m_ = 1.0 / layer_m_;
    if (static_cast<double>(nx_) * ny_ * nl_ > 1e8)
        throw std::invalid_argument("scene grid too large");
}

ForestScene::CellRange ForestScene::cellRange(const Box &b) const {
    CellRange r;
    r.ix0 = std::clamp(static_cast<int>(std::floor((b.xmin - x0_) / cell_)), 0, nx_ - 1);
    r.ix1 = std::clamp(static_cast<int>(std::floor((b.xmax - x0_) / cell_)), 0, nx_ - 1);
    r.iy0 = std::clamp(static_cast<int>(std::floor((b.ymin - y0_) / cell_)), 0, ny_ - 1);
    r.iy1 = std::clamp(static_cast<int>(std::floor((b.ymax - y0_) / cell_)), 0, ny_ - 1);
    r.l0 = layerOf(b.zmin);
    r.l1 = layerOf(b.zmax);
    return r;
}

template <class Visit>
void ForestScene::forEachCell(const Box &b, Visit &&visit) const {
    const CellRange r = cellRange(b);
    for (int iy = r.iy0; iy <= r.iy1; ++iy)
        for (int ix = r.ix0; ix <= r.ix1; ++ix)
            visit(static_cast<size_t>(iy) * nx_ + ix, r.l0, r.l1);
}

void ForestScene::binPrimitives(const std::vector<Box> &boxes) {
    // Two passes (CSR lists): count the items of every bin and cell, then fill them in the order
    // of the primitives' rows.
    const size_t ncell = static_cast<size_t>(nx_) * ny_;
    const size_t nbin = ncell * nl_;
    std::vector<uint32_t> count(nbin + 1, 0), cell_count(ncell + 1, 0);
    cell_layers_.assign(ncell, 0);
    for (const Box &b : boxes)
        forEachCell(b, [&](size_t c, int l0, int l1) {
            ++cell_count[c + 1];
            for (int l = l0; l <= l1; ++l) {
                ++count[c * nl_ + l + 1];
                cell_layers_[c] |= uint64_t{1} << l;
            }
        });
    for (size_t c = 0; c < nbin; ++c) count[c + 1] += count[c];
    for (size_t c = 0; c < ncell; ++c) cell_count[c + 1] += cell_count[c];
    bin_start_ = count;
    bin_items_.resize(count[nbin]);
    std::vector<uint32_t> fill(bin_start_.begin(), bin_start_.end() - 1);
    cell_start_ = cell_count;
    cell_items_.resize(cell_count[ncell]);
    std::vector<uint32_t> cell_fill(cell_start_.begin(), cell_start_.end() - 1);
    prims_.resize(boxes.size());
    for (size_t row = 0; row < boxes.size(); ++row) {
        prims_[row] = compactPrim(boxes[row]);
        const uint32_t item = static_cast<uint32_t>(row);
        forEachCell(boxes[row], [&](size_t c, int l0, int l1) {
            cell_items_[cell_fill[c]++] = item;
            for (int l = l0; l <= l1; ++l) bin_items_[fill[c * nl_ + l]++] = item;
        });
    }
}

ForestScene::Prim ForestScene::compactPrim(const Box &b) const {
    const double m = 1e-6;  // keep the rejection conservative under round-off
    return Prim{
        {floatDown(b.xmin - m - x0_), floatDown(b.ymin - m - y0_), floatDown(b.zmin - m - z0_)},
        {floatUp(b.xmax + m - x0_), floatUp(b.ymax + m - y0_), floatUp(b.zmax + m - z0_)},
        b.code,
        0};
}

bool ForestScene::testPrimitive(uint32_t code, const Ray &ray, double t_max, Hit &hit) const {
    const uint32_t index = code & kIndexMask;
    switch (code & ~kIndexMask) {
        case kStemCode:
            if (!intersectStem(stems_[index], stem_coeffs_[index], ray, t_max, hit)) return false;
            hit.surface = kStem;
            break;
        case kCylinderCode:
            if (!intersectCylinder(cylinders_[index], cylinder_coeffs_[index], ray, t_max, hit))
                return false;
            hit.surface = cylinders_[index].surface;
            break;
        default:
            if (!intersectFoliage(foliage_[index], foliage_coeffs_[index],
                                  static_cast<int32_t>(index), ray, t_max, hit))
                return false;
            hit.surface = foliage_[index].surface;
            break;
    }
    hit.object = static_cast<int32_t>(index);
    if ((code & ~kIndexMask) == kStemCode && stems_[index].tree >= 0)
        hit.object = stems_[index].tree;
    return true;
}

bool ForestScene::startCast(const Ray &ray, const GridRay &grid_ray, Hit &best, double &t,
                            double &t1) const {
    terrain_.intersect(ray, grid_ray, ray.t_max, best);
    if (nx_ == 0) return false;
    const double ox = ray.origin.x(), oy = ray.origin.y(), oz = ray.origin.z();
    const double dz = ray.dir.z();
    t = ray.t_min;
    t1 = std::min(ray.t_max, best.t);
    if (dz > 0.0) {  // a rising ray is done once above every primitive
        if (oz > z_max_) return false;
        t1 = std::min(t1, (z_max_ - oz) / dz + 1e-9);
    }
    // Clipped to the grid's XY slab.
    const double xmax = x0_ + nx_ * cell_, ymax = y0_ + ny_ * cell_;
    if (grid_ray.inv_dx == 0.0) {
        if (ox < x0_ || ox > xmax) return false;
    } else {
        const double ta = (x0_ - ox) * grid_ray.inv_dx, tb = (xmax - ox) * grid_ray.inv_dx;
        t = std::max(t, std::min(ta, tb));
        t1 = std::min(t1, std::max(ta, tb));
    }
    if (grid_ray.inv_dy == 0.0) {
        if (oy < y0_ || oy > ymax) return false;
    } else {
        const double ta = (y0_ - oy) * grid_ray.inv_dy, tb = (ymax - oy) * grid_ray.inv_dy;
        t = std::max(t, std::min(ta, tb));
        t1 = std::min(t1, std::max(ta, tb));
    }
    return t <= t1;
}

namespace {

// The 2D DDA over the primitive grid's cells, written out here (not traverseGrid) so that an
// empty cell costs a few operations in cast(): the current cell, the ray parameters of the next
// x and y cell boundaries, and their spacing.
struct CellWalk {
    int ix, iy, sx, sy;
    double tnx = kInf, tny = kInf, tdx = kInf, tdy = kInf;

    CellWalk(const Ray &ray, const GridRay &g, double t, double x0, double y0, double cell,
             double inv_cell, int nx, int ny) {
        const double ox = ray.origin.x(), oy = ray.origin.y();
        const double dx = ray.dir.x(), dy = ray.dir.y();
        ix = std::clamp(static_cast<int>(std::floor((ox + t * dx - x0) * inv_cell)), 0, nx - 1);
        iy = std::clamp(static_cast<int>(std::floor((oy + t * dy - y0) * inv_cell)), 0, ny - 1);
        sx = dx > 0 ? 1 : -1;
        sy = dy > 0 ? 1 : -1;
        if (g.inv_dx != 0.0) {
            tnx = ((dx > 0 ? x0 + (ix + 1) * cell : x0 + ix * cell) - ox) * g.inv_dx;
            tdx = cell * std::abs(g.inv_dx);
        }
        if (g.inv_dy != 0.0) {
            tny = ((dy > 0 ? y0 + (iy + 1) * cell : y0 + iy * cell) - oy) * g.inv_dy;
            tdy = cell * std::abs(g.inv_dy);
        }
    }
    double exitT() const { return std::min(tnx, tny); }
    // Into the next cell (t: where the ray enters it); false when that leaves the grid.
    bool step(double &t, int nx, int ny) {
        if (tnx < tny) {
            ix += sx;
            t = tnx;
            tnx += tdx;
            return ix >= 0 && ix < nx;
        }
        iy += sy;
        t = tny;
        tny += tdy;
        return iy >= 0 && iy < ny;
    }
};

}  // namespace

// Rows of prims_ a ray has already tested exactly (the last 8): a primitive lies in several
// bins, and testing it again cannot change the result (the exact tests cover the whole ray,
// t_max only shrinks).
struct ForestScene::RecentRows {
    uint32_t rows[8];
    unsigned n = 0;
    // True the first time a row comes (within the last 8).
    bool firstTime(uint32_t row) {
        bool seen = false;
        for (unsigned j = 0; j < std::min(n, 8u); ++j) seen |= rows[j] == row;
        if (seen) return false;
        rows[n++ & 7u] = row;
        return true;
    }
};

Hit ForestScene::cast(const Ray &ray) const {
    Hit best;
    const GridRay grid_ray(ray);
    double t, t1;
    if (!startCast(ray, grid_ray, best, t, t1)) return best;
    CellWalk walk(ray, grid_ray, t, x0_, y0_, cell_, inv_cell_, nx_, ny_);
    // Layer coordinate along the ray, widened by a hair so round-off never drops a layer.
    const double lz0 = (ray.origin.z() - z0_) * inv_layer_m_, ldz = ray.dir.z() * inv_layer_m_;
    const double lmax = nl_ - 1.0;
    const uint64_t *layers = cell_layers_.data();
    RecentRows tested;
    double t_stop = std::min(t1, best.t);  // the walk ends at the grid exit or the best hit
    while (true) {
        const double tn = walk.exitT();
        const double t_hi = std::max(t, std::min(tn, t_stop));
        double la = lz0 + t * ldz, lb = lz0 + t_hi * ldz;
        if (la > lb) std::swap(la, lb);
        const int l0 = static_cast<int>(std::clamp(la - 1e-9, 0.0, lmax));
        const int l1 = static_cast<int>(std::clamp(lb + 1e-9, 0.0, lmax));
        const size_t c = static_cast<size_t>(walk.iy) * nx_ + walk.ix;
        const uint64_t span = l1 - l0 >= 63 ? ~uint64_t{0} : (uint64_t{2} << (l1 - l0)) - 1;
        if ((layers[c] >> l0) & span) {
            testCell(ray, c, l0, l1, t, t_hi, best, tested);
            t_stop = std::min(t1, best.t);
        }
        if (t_stop <= tn) break;  // the best hit lies in this cell, or the walk is done
        if (!walk.step(t, nx_, ny_)) break;
    }
    return best;
}

void ForestScene::testCell(const Ray &ray, size_t c, int l0, int l1, double t, double t_hi,
                           Hit &best, RecentRows &tested) const {
    // The bins of a cell are consecutive layers, so the layers the ray crosses here are one
    // contiguous run of items.
    const size_t first = c * nl_;
    const uint32_t k0 = bin_start_[first + l0];
    const uint32_t k1 = bin_start_[first + l1 + 1];
    // The ray's segment [t, t_hi] in a box relative to the grid origin, compared in double with
    // the (exactly widened) float boxes.
    const double ox = ray.origin.x(), oy = ray.origin.y(), oz = ray.origin.z();
    const double dx = ray.dir.x(), dy = ray.dir.y(), dz = ray.dir.z();
    const double xa = ox + t * dx, xb = ox + t_hi * dx;
    const double ya = oy + t * dy, yb = oy + t_hi * dy;
    const double za = oz + t * dz, zb = oz + t_hi * dz;
    const double rx_lo = std::min(xa, xb) - x0_, rx_hi = std::max(xa, xb) - x0_;
    const double ry_lo = std::min(ya, yb) - y0_, ry_hi = std::max(ya, yb) - y0_;
    const double rz_lo = std::min(za, zb) - z0_, rz_hi = std::max(za, zb) - z0_;
    const Prim *prims = prims_.data();
    const uint32_t *items = bin_items_.data();
    for (uint32_t k = k0; k < k1; ++k) {
        const uint32_t row = items[k];
        const Prim &p = prims[row];
        if (p.lo[0] > rx_hi || p.hi[0] < rx_lo || p.lo[1] > ry_hi || p.hi[1] < ry_lo ||
            p.lo[2] > rz_hi || p.hi[2] < rz_lo)
            continue;
        if (!tested.firstTime(row)) continue;
        Hit h;
        if (testPrimitive(p.code, ray, std::min(best.t, ray.t_max), h) && h.t < best.t) best = h;
    }
}

namespace {
// Bundling limits: rays within 60 degrees of the walk axis, not steeper than about 87 degrees,
// a fan of at most 0.2 in XY slope (about 11 degrees: two 31-ray groups of an RS-M1 raster
// row; 0.05 was 10 % slower there and no faster for spinning sensors; much wider fans make
// the shared walk cover many cells no single ray crosses), and origins within 1 cm of the
// first ray's (successive firing columns of a moving sensor are a fraction of a millimetre
// apart).
constexpr double kBundleMinAxis = 0.5;
constexpr double kBundleMinHorizontal = 0.05;
constexpr double kBundleMaxSlopeSpread = 0.2;
constexpr double kBundleMaxOriginSpread = 0.01;
}  // namespace

void ForestScene::castBatch(const Ray *rays, size_t n, Hit *hits) const {
    if (nx_ == 0) {
        for (size_t i = 0; i < n; ++i) hits[i] = cast(rays[i]);
        return;
    }
    std::vector<uint32_t> stamp;
    uint32_t id = 0;
    size_t i = 0;
    while (i < n) {
        const Ray &r0 = rays[i];
        const bool along_x = std::abs(r0.dir.x()) >= std::abs(r0.dir.y());
        // XY slope of a ray relative to the walk axis; false when it cannot join a bundle.
        auto slope = [&](const Ray &r, double &s) {
            const double du = along_x ? r.dir.x() : r.dir.y();
            const double dv = along_x ? r.dir.y() : r.dir.x();
            const double h = std::sqrt(du * du + dv * dv);
            if (!(h >= kBundleMinHorizontal) || !(std::abs(du) >= kBundleMinAxis * h) ||
                !std::isfinite(r.dir.z()) || !(r.t_min >= 0.0) ||
                (du > 0) != (r0.dir[along_x ? 0 : 1] > 0))
                return false;
            s = dv / du;
            return true;
        };
        size_t j = i + 1;
        double s0;
        if (r0.origin.allFinite() && slope(r0, s0)) {
            double s_lo = s0, s_hi = s0;
            while (j < n && j - i < static_cast<size_t>(kMaxBundle)) {
                const Ray &r = rays[j];
                double s;
                if (!r.origin.allFinite() ||
                    !((r.origin - r0.origin).cwiseAbs().maxCoeff() <= kBundleMaxOriginSpread) ||
                    !slope(r, s))
                    break;
                const double lo = std::min(s_lo, s), hi = std::max(s_hi, s);
                if (hi - lo > kBundleMaxSlopeSpread) break;
                s_lo = lo;
                s_hi = hi;
                ++j;
            }
        }
        if (j - i == 1) {
            hits[i] = cast(r0);
        } else {
            if (stamp.empty()) stamp.assign(prims_.size(), 0);
            if (++id == 0) {  // wrapped: start the marks afresh
                std::fill(stamp.begin(), stamp.end(), 0);
                id = 1;
            }
            castBundle(rays + i, static_cast<int>(j - i), along_x, hits + i, stamp.data(), id);
        }
        i = j;
    }
}

// The state of one bundle's walk along the grid columns (castBundle), shared by its stages.
// Along the walk axis u all rays of the bundle advance together: a ray is at the offset
// a = |u - u_origin| at t = a / |du|, where it is at v_origin + a sv and z_origin + a kz.
// One lane per ray still walking, sorted by kz: its segment inside the grid as offsets
// [a_lo, a_stop] (a_stop: grid exit, end of range, or the best hit so far).
struct ForestScene::BundleWalk {
    struct Lane {
        int k;
        double a_lo, a_stop, adu, sv, kz;
    };
    const Ray *rays;
    Hit *hits;
    Lane lanes[kMaxBundle];
    int n_active = 0;
    // Largest distance (per axis) of a ray's origin from the first ray's, from which the walk
    // runs: a ray translated to the first origin meets a box grown by eps wherever the ray
    // itself meets the box, so all rejections use boxes grown by eps.
    double eps = 0.0;
    double su = 1.0;     // direction of the walk along u (+1 / -1)
    int au = 0, av = 1;  // axes of u and v in x, y
    double ro[3];        // first origin relative to the boxes (x0_, y0_, z0_)
    double ou = 0.0;     // first origin along u
    // Fan of the active lanes across (sv) and their nearest end (a_stop), refreshed when a lane
    // leaves; the lanes stay sorted by kz.
    double sv_lo = kInf, sv_hi = -kInf, a_stop_min = kInf;

    void refresh() {
        sv_lo = kInf;
        sv_hi = -kInf;
        a_stop_min = kInf;
        for (int a = 0; a < n_active; ++a) {
            sv_lo = std::min(sv_lo, lanes[a].sv);
            sv_hi = std::max(sv_hi, lanes[a].sv);
            a_stop_min = std::min(a_stop_min, lanes[a].a_stop);
        }
    }
    // Lanes whose segment ends before offset a_done are done.
    void retire(double a_done) {
        if (a_stop_min > a_done) return;
        int w = 0;
        for (int a = 0; a < n_active; ++a)
            if (lanes[a].a_stop > a_done) lanes[w++] = lanes[a];
        n_active = w;
        refresh();
    }
};

void ForestScene::castBundle(const Ray *rays, int n, bool along_x, Hit *hits, uint32_t *stamp,
                             uint32_t id) const {
    BundleWalk w;
    w.rays = rays;
    w.hits = hits;
    startBundle(w, n, along_x);
    if (w.n_active == 0) return;
    const int step = w.su > 0 ? 1 : -1;
    const double u0 = along_x ? x0_ : y0_;
    const int nu = along_x ? nx_ : ny_;
    // From the column of the rearmost origin: the others start up to eps behind the first.
    int iu = static_cast<int>(
        std::clamp(std::floor((w.ou - w.su * w.eps - u0) * inv_cell_), 0.0, nu - 1.0));
    for (; w.n_active > 0 && iu >= 0 && iu < nu; iu += step) {
        // Offsets of this column's near and far boundaries from the first origin (its column
        // and any behind it from a = 0).
        const double a1 = w.su * (u0 + (w.su > 0 ? iu + 1 : iu) * cell_ - w.ou);
        // The lanes' paths over the column, grown by eps along the walk (a point of a ray is
        // within eps of its translate, whose offset a may then lie just outside the column).
        const double a0 =
            std::max(0.0, w.su * (u0 + (w.su > 0 ? iu : iu + 1) * cell_ - w.ou) - w.eps);
        const double a1e = a1 + w.eps;
        if (a1e >= a0) walkColumn(w, along_x, iu, a0, a1e, stamp, id);
        // Lanes whose segment ends in this column are done (kept one column more when the
        // end lies within round-off of the boundary).
        w.retire(a1 - w.eps - 1e-9);
    }
}

void ForestScene::startBundle(BundleWalk &w, int n, bool along_x) const {
    const Ray *rays = w.rays;
    const Eigen::Vector3d &o = rays[0].origin;
    for (int k = 0; k < n; ++k) {
        // Terrain and the segment to walk exactly as cast() does, from the ray's own origin.
        const Ray &ray = rays[k];
        w.eps = std::max(w.eps, (ray.origin - o).cwiseAbs().maxCoeff());
        Hit &best = w.hits[k];
        best = Hit();
        double t, t1;
        if (!startCast(ray, GridRay(ray), best, t, t1)) continue;
        const double dz = ray.dir.z();
        BundleWalk::Lane &l = w.lanes[w.n_active++];
        l.k = k;
        const double du = along_x ? ray.dir.x() : ray.dir.y();
        const double dv = along_x ? ray.dir.y() : ray.dir.x();
        l.adu = std::abs(du);
        const double inv_adu = 1.0 / l.adu;
        l.sv = dv * inv_adu;
        l.kz = dz * inv_adu;
        l.a_lo = t * l.adu;
        l.a_stop = std::min(t1, best.t) * l.adu;
    }
    if (w.n_active == 0) return;
    std::sort(w.lanes, w.lanes + w.n_active,
              [](const BundleWalk::Lane &a, const BundleWalk::Lane &b) { return a.kz < b.kz; });
    w.su = (along_x ? rays[0].dir.x() : rays[0].dir.y()) > 0 ? 1.0 : -1.0;
    w.au = along_x ? 0 : 1;
    w.av = along_x ? 1 : 0;
    w.ro[0] = o.x() - x0_;
    w.ro[1] = o.y() - y0_;
    w.ro[2] = o.z() - z0_;
    w.ou = along_x ? o.x() : o.y();
    w.refresh();
}

void ForestScene::walkColumn(BundleWalk &w, bool along_x, int iu, double a0, double a1e,
                             uint32_t *stamp, uint32_t id) const {
    const int au = w.au, av = w.av;
    const double *ro = w.ro;
    // Box of all lanes' paths in this column, grid-relative, widened by eps and a hair so that
    // round-off never drops a cell, a layer or a primitive.
    const double m = 1e-7 + w.eps;
    const double kz_lo = w.lanes[0].kz, kz_hi = w.lanes[w.n_active - 1].kz;
    double lo[3], hi[3];
    lo[au] = ro[au] + std::min(w.su * a0, w.su * a1e) - m;
    hi[au] = ro[au] + std::max(w.su * a0, w.su * a1e) + m;
    lo[av] = ro[av] + std::min(a0 * w.sv_lo, a1e * w.sv_lo) - m;
    hi[av] = ro[av] + std::max(a0 * w.sv_hi, a1e * w.sv_hi) + m;
    lo[2] = ro[2] + std::min(a0 * kz_lo, a1e * kz_lo) - m;
    hi[2] = ro[2] + std::max(a0 * kz_hi, a1e * kz_hi) + m;
    const int nv = along_x ? ny_ : nx_;
    const double lmax = nl_ - 1.0;
    const int iv0 = static_cast<int>(std::clamp(std::floor(lo[av] * inv_cell_), 0.0, nv - 1.0));
    const int iv1 = static_cast<int>(std::clamp(std::floor(hi[av] * inv_cell_), 0.0, nv - 1.0));
    const int l0 = static_cast<int>(std::clamp(lo[2] * inv_layer_m_, 0.0, lmax));
    const int l1 = static_cast<int>(std::clamp(hi[2] * inv_layer_m_, 0.0, lmax));
    const uint64_t span = l1 - l0 >= 63 ? ~uint64_t{0} : (uint64_t{2} << (l1 - l0)) - 1;
    const uint64_t *layers = cell_layers_.data();
    const Prim *prims = prims_.data();
    const uint32_t *items = cell_items_.data();
    const uint32_t *starts = cell_start_.data();
    for (int iv = iv0; iv <= iv1; ++iv) {
        const size_t c =
            along_x ? static_cast<size_t>(iv) * nx_ + iu : static_cast<size_t>(iu) * nx_ + iv;
        if (!((layers[c] >> l0) & span)) continue;
        for (uint32_t q = starts[c], q1 = starts[c + 1]; q < q1; ++q) {
            const uint32_t row = items[q];
            if (stamp[row] == id) continue;
            const Prim &p = prims[row];
            if (p.lo[0] > hi[0] || p.hi[0] < lo[0] || p.lo[1] > hi[1] || p.hi[1] < lo[1] ||
                p.lo[2] > hi[2] || p.hi[2] < lo[2])
                continue;  // may still meet the bundle in a later column
            stamp[row] = id;
            testLanes(w, p);
        }
    }
}

void ForestScene::testLanes(BundleWalk &w, const Prim &p) const {
    // Tested once for the bundle: each lane whose whole segment can meet the box, i.e. whose a
    // range overlaps the box's and whose slopes sv and kz reach the box's v and z extents over
    // it (for kz a contiguous run of the sorted lanes). The slope bounds hold over the whole
    // box, so a box no active lane's slope reaches is done with for the bundle.
    const int au = w.au, av = w.av;
    const double *ro = w.ro;
    const double eps = w.eps, su = w.su;
    const double pa0 = su * (p.lo[au] - ro[au]), pa1 = su * (p.hi[au] - ro[au]);
    const double pa_lo = std::min(pa0, pa1) - eps;
    const double pa_hi = std::max(pa0, pa1) + eps;
    double k_lo = -kInf, k_hi = kInf, s_lo = -kInf, s_hi = kInf;
    if (pa_lo > 0.0) {
        const double r_lo = 1.0 / pa_lo, r_hi = 1.0 / pa_hi;
        const double bv0 = p.lo[av] - ro[av] - eps;
        const double bv1 = p.hi[av] - ro[av] + eps;
        s_lo = std::min(bv0 * r_lo, bv0 * r_hi);
        s_hi = std::max(bv1 * r_lo, bv1 * r_hi);
        if (s_lo > w.sv_hi || s_hi < w.sv_lo) return;
        const double bz0 = p.lo[2] - ro[2] - eps;
        const double bz1 = p.hi[2] - ro[2] + eps;
        k_lo = std::min(bz0 * r_lo, bz0 * r_hi);
        k_hi = std::max(bz1 * r_lo, bz1 * r_hi);
    }
    BundleWalk::Lane *lanes = w.lanes;
    const int n_active = w.n_active;
    int a = 0;
    if (k_lo > lanes[0].kz)
        a = static_cast<int>(
            std::partition_point(lanes, lanes + n_active,
                                 [&](const BundleWalk::Lane &l) { return l.kz < k_lo; }) -
            lanes);
    for (; a < n_active && lanes[a].kz <= k_hi; ++a) {
        BundleWalk::Lane &l = lanes[a];
        if (l.sv < s_lo || l.sv > s_hi || pa_lo > l.a_stop || pa_hi < l.a_lo) continue;
        const Ray &ray = w.rays[l.k];
        Hit &best = w.hits[l.k];
        Hit h;
        if (testPrimitive(p.code, ray, std::min(best.t, ray.t_max), h) && h.t < best.t) {
            best = h;
            l.a_stop = std::min(l.a_stop, h.t * l.adu);
            w.a_stop_min = std::min(w.a_stop_min, l.a_stop);
        }
    }
}

CastResult ForestScene::castRays(const Eigen::Ref<const Points3> &origins,
                                 const Eigen::Ref<const Points3> &dirs, double range_min,
                                 double range_max, uint64_t seed) const {
    const Eigen::Index n = dirs.rows(), n_origins = origins.rows();
    if (n_origins == 0 || n % n_origins != 0)
        throw std::invalid_argument(
            "origins must have one row, one row per direction, or divide the directions into "
            "equal consecutive groups");
    const Eigen::Index per_origin = n / n_origins;
    CastResult out;
    out.range.setConstant(n, std::nan(""));
    out.surface.setZero(n);
    out.object.setConstant(n, -1);
    out.cos_incidence.setZero(n);
    // In chunks of a few thousand rays: memory stays small for millions of rays, and rays
    // sharing an origin are still cast together (castBatch gives the same hits wherever a chunk
    // ends).
    constexpr Eigen::Index kChunk = 4096;
    std::vector<Ray> rays;
    std::vector<Eigen::Index> rows;
    std::vector<Hit> hits;
    rays.reserve(kChunk);
    rows.reserve(kChunk);
    for (Eigen::Index begin = 0; begin < n; begin += kChunk) {
        const Eigen::Index end = std::min(n, begin + kChunk);
        rays.clear();
        rows.clear();
        for (Eigen::Index i = begin; i < end; ++i) {
            Ray ray;
            ray.origin = origins.row(i / per_origin).transpose();
            ray.dir = dirs.row(i).transpose();
            const double norm = ray.dir.norm();
            if (!(norm > 0.0) || !ray.origin.allFinite() || !std::isfinite(norm)) continue;
            ray.dir /= norm;
            ray.t_min = 0.0;  // anything closer than range_min still blocks the beam
            ray.t_max = range_max;
            ray.key = mixKey(seed, static_cast<uint64_t>(i));
            rays.push_back(ray);
            rows.push_back(i);
        }
        hits.resize(rays.size());
        castBatch(rays.data(), rays.size(), hits.data());
        for (size_t q = 0; q < rays.size(); ++q) {
            const Hit &hit = hits[q];
            const Eigen::Index i = rows[q];
            if (!hit.valid() || hit.t < range_min) continue;
            out.range[i] = hit.t;
            out.surface[i] = hit.surface;
            out.object[i] = hit.object;
            out.cos_incidence[i] = hit.cos_incidence;
        }
    }
    return out;
}

}  // namespace forestslam::sim
