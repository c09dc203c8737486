// 2D DDA (Amanatides & Woo) over a uniform grid; included by forest_scene.hpp.
#pragma once

#include <algorithm>
#include <cmath>

namespace forestslam::sim {

inline GridRay::GridRay(const Ray &ray)
    : ox(ray.origin.x()),
      oy(ray.origin.y()),
      dx(ray.dir.x()),
      dy(ray.dir.y()),
      inv_dx(std::abs(ray.dir.x()) < 1e-15 ? 0.0 : 1.0 / ray.dir.x()),
      inv_dy(std::abs(ray.dir.y()) < 1e-15 ? 0.0 : 1.0 / ray.dir.y()) {}

template <class Visit>
void traverseGrid(double x0, double y0, double cell, int nx, int ny, const Ray &ray, double t0,
                  double t1, Visit &&visit) {
    traverseGrid(x0, y0, cell, 1.0 / cell, nx, ny, GridRay(ray), t0, t1, visit);
}

template <class Visit>
void traverseGrid(double x0, double y0, double cell, double inv_cell, int nx, int ny,
                  const GridRay &r, double t0, double t1, Visit &&visit) {
    if (nx <= 0 || ny <= 0) return;
    const double ox = r.ox, oy = r.oy;
    const double xmax = x0 + nx * cell, ymax = y0 + ny * cell;
    // Clip to the grid's XY slab.
    if (r.inv_dx == 0.0) {
        if (ox < x0 || ox > xmax) return;
    } else {
        const double ta = (x0 - ox) * r.inv_dx, tb = (xmax - ox) * r.inv_dx;
        t0 = std::max(t0, std::min(ta, tb));
        t1 = std::min(t1, std::max(ta, tb));
    }
    if (r.inv_dy == 0.0) {
        if (oy < y0 || oy > ymax) return;
    } else {
        const double ta = (y0 - oy) * r.inv_dy, tb = (ymax - oy) * r.inv_dy;
        t0 = std::max(t0, std::min(ta, tb));
        t1 = std::min(t1, std::max(ta, tb));
    }
    if (!(t0 <= t1)) return;
    const double px = ox + t0 * r.dx, py = oy + t0 * r.dy;
    int ix = std::clamp(static_cast<int>(std::floor((px - x0) * inv_cell)), 0, nx - 1);
    int iy = std::clamp(static_cast<int>(std::floor((py - y0) * inv_cell)), 0, ny - 1);
    const int sx = r.dx > 0 ? 1 : -1, sy = r.dy > 0 ? 1 : -1;
    double tnx = kInf, tny = kInf, tdx = kInf, tdy = kInf;
    if (r.inv_dx != 0.0) {
        tnx = ((r.dx > 0 ? x0 + (ix + 1) * cell : x0 + ix * cell) - ox) * r.inv_dx;
        tdx = cell * std::abs(r.inv_dx);
    }
    if (r.inv_dy != 0.0) {
        tny = ((r.dy > 0 ? y0 + (iy + 1) * cell : y0 + iy * cell) - oy) * r.inv_dy;
        tdy = cell * std::abs(r.inv_dy);
    }
    double t = t0;
    while (true) {
        const double tn = std::min(tnx, tny);
        const double t_exit = std::min(tn, t1);
        if (!visit(ix, iy, t, std::max(t, t_exit))) return;
        if (tn >= t1) return;
        if (tnx < tny) {
            ix += sx;
            t = tnx;
            tnx += tdx;
            if (ix < 0 || ix >= nx) return;
        } else {
            iy += sy;
            t = tny;
            tny += tdy;
            if (iy < 0 || iy >= ny) return;
        }
    }
}

}  // namespace forestslam::sim
