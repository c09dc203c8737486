// 2D DDA (Amanatides & Woo) over a uniform grid; included by forest_scene.hpp.
#pragma once

#include <algorithm>
#include <cmath>

namespace forestslam::sim {

template <class Visit>
void traverseGrid(double x0, double y0, double cell, int nx, int ny, const Ray &ray, double t0,
                  double t1, Visit &&visit) {
    if (nx <= 0 || ny <= 0) return;
    const double ox = ray.origin.x(), oy = ray.origin.y();
    const double dx = ray.dir.x(), dy = ray.dir.y();
    const double xmax = x0 + nx * cell, ymax = y0 + ny * cell;
    // Clip to the grid's XY slab.
    if (std::abs(dx) < 1e-15) {
        if (ox < x0 || ox > xmax) return;
    } else {
        const double ta = (x0 - ox) / dx, tb = (xmax - ox) / dx;
        t0 = std::max(t0, std::min(ta, tb));
        t1 = std::min(t1, std::max(ta, tb));
    }
    if (std::abs(dy) < 1e-15) {
        if (oy < y0 || oy > ymax) return;
    } else {
        const double ta = (y0 - oy) / dy, tb = (ymax - oy) / dy;
        t0 = std::max(t0, std::min(ta, tb));
        t1 = std::min(t1, std::max(ta, tb));
    }
    if (!(t0 <= t1)) return;
    const double px = ox + t0 * dx, py = oy + t0 * dy;
    int ix = std::clamp(static_cast<int>(std::floor((px - x0) / cell)), 0, nx - 1);
    int iy = std::clamp(static_cast<int>(std::floor((py - y0) / cell)), 0, ny - 1);
    const int sx = dx > 0 ? 1 : -1, sy = dy > 0 ? 1 : -1;
    double tnx = kInf, tny = kInf, tdx = kInf, tdy = kInf;
    if (std::abs(dx) >= 1e-15) {
        tnx = ((dx > 0 ? x0 + (ix + 1) * cell : x0 + ix * cell) - ox) / dx;
        tdx = cell / std::abs(dx);
    }
    if (std::abs(dy) >= 1e-15) {
        tny = ((dy > 0 ? y0 + (iy + 1) * cell : y0 + iy * cell) - oy) / dy;
        tdy = cell / std::abs(dy);
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
