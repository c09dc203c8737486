#include "forestslam/perception/segmentation.hpp"

#include <pcl/kdtree/kdtree_flann.h>
#include <pcl/search/kdtree.h>
#include <pcl/segmentation/extract_clusters.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <deque>
#include <map>
#include <numeric>

#include "forestslam/common/pcl_adapter.hpp"

namespace forestslam::perception {
namespace {

constexpr double kPi = 3.14159265358979323846;

struct UnionFind {
    std::vector<int> parent;
    explicit UnionFind(int n) : parent(static_cast<size_t>(n)) {
        std::iota(parent.begin(), parent.end(), 0);
    }
    int find(int a) {
        while (parent[a] != a) a = parent[a] = parent[parent[a]];
        return a;
    }
    void unite(int a, int b) { parent[find(a)] = find(b); }
};

pcl::PointCloud<pcl::PointXYZ>::Ptr subsetCloud(const Eigen::Ref<const Points3> &points,
                                                const std::vector<int> &rows) {
    pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
    cloud->resize(rows.size());
    for (size_t k = 0; k < rows.size(); ++k) {
        const int i = rows[k];
        (*cloud)[k] =
            pcl::PointXYZ(static_cast<float>(points(i, 0)), static_cast<float>(points(i, 1)),
                          static_cast<float>(points(i, 2)));
    }
    return cloud;
}

}  // namespace

RangeImageProjection projectToRangeImage(const Eigen::Ref<const Points3> &points,
                                         const Eigen::Ref<const Eigen::VectorXi> &ring,
                                         const SensorGeometry &s) {
    const Eigen::Index n = points.rows();
    requirePerPoint("projectToRangeImage", "rings", ring.size(), n, true);
    RangeImageProjection p;
    p.row.assign(static_cast<size_t>(n), -1);
    p.col.assign(static_cast<size_t>(n), -1);
    if (s.image_rows <= 0 || s.image_cols <= 0) return p;
    const bool use_ring = ring.size() == n;
    const bool wrap = s.horizontal_fov_rad >= 2 * kPi - 1e-6;
    const std::vector<double> &va = s.vertical_angles_rad;
    const double tol = std::max(s.theta_v_rad, 1e-4);
    for (Eigen::Index i = 0; i < n; ++i) {
        const double x = points(i, 0), y = points(i, 1), z = points(i, 2);
        if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) continue;
        int row = -1;
        if (use_ring) {
            row = ring(i);
        } else if (!va.empty()) {
            const double el = std::atan2(z, std::hypot(x, y));
            auto it = std::lower_bound(va.begin(), va.end(), el);
            size_t k = static_cast<size_t>(it - va.begin());
            if (k == va.size() || (k > 0 && el - va[k - 1] < va[k] - el)) k = k - 1;
            if (std::abs(el - va[k]) <= tol) row = static_cast<int>(k);
        }
        if (row < 0 || row >= s.image_rows) continue;
        const double az = std::atan2(y, x);
        int col;
        if (wrap) {
            col = static_cast<int>(std::floor((az + kPi) / (2 * kPi) * s.image_cols));
            col = ((col % s.image_cols) + s.image_cols) % s.image_cols;
        } else {
            const double u = (az + 0.5 * s.horizontal_fov_rad) / s.horizontal_fov_rad;
            if (u < 0 || u >= 1) continue;
            col = std::min(static_cast<int>(u * s.image_cols), s.image_cols - 1);
        }
        p.row[static_cast<size_t>(i)] = row;
        p.col[static_cast<size_t>(i)] = col;
    }
    return p;
}

namespace {

// The range image as a graph: pixels (each represented by its nearest point) and the
// angle-based connectivity test between two points (Bogoslavskyi & Stachniss).
struct PixelGraph {
    const Eigen::Ref<const Points3> &points;
    const SegmentationConfig &opt;
    int R, C, gap, B;
    double col_rad;
    std::vector<double> range;  // per point
    std::vector<int> pix;       // per pixel: its nearest point, -1: empty

    // Two points are one surface when the angle beta between the farther beam and the line
    // joining them is wide enough and they are not too far apart.
    bool connected(int a, int b) const {
        const double da = range[a], db = range[b];
        if (da <= 0 || db <= 0) return false;
        const double d1 = std::max(da, db), d2 = std::min(da, db);
        const double cos_alpha =
            std::clamp(points.row(a).dot(points.row(b)) / (da * db), -1.0, 1.0);
        const double alpha = std::acos(cos_alpha);
        const double beta = std::atan2(d2 * std::sin(alpha), d1 - d2 * cos_alpha);
        const double dist = (points.row(a) - points.row(b)).norm();
        return beta > opt.beta_min_rad && dist < opt.max_neighbour_gap_m + 1.5 * alpha * d2;
    }
    // Near the sensor the voxel thinning before this step leaves several empty columns between
    // the points of one surface: bridge up to max_gap_m of arc horizontally there (a stem at 2 m
    // otherwise falls apart into vertical strips, and strips of neighbouring stems then merge).
    int colGap(int pixel) const {
        const double d = range[static_cast<size_t>(pix[static_cast<size_t>(pixel)])];
        if (!(opt.max_gap_m > 0) || !(d > 0) || !(col_rad > 0)) return gap;
        const double cols = opt.max_gap_m / (d * col_rad);
        return std::max(gap, static_cast<int>(std::min<double>(cols, B)));
    }
};

// Nearest point per pixel represents it.
void nearestPerPixel(PixelGraph &g, const RangeImageProjection &proj) {
    const Eigen::Index n = g.points.rows();
    g.range.resize(static_cast<size_t>(n));
    for (Eigen::Index i = 0; i < n; ++i) g.range[i] = g.points.row(i).norm();
    g.pix.assign(static_cast<size_t>(g.R) * g.C, -1);
    for (Eigen::Index i = 0; i < n; ++i) {
        const int r = proj.row[i], c = proj.col[i];
        if (r < 0 || c < 0) continue;
        int &slot = g.pix[static_cast<size_t>(r) * g.C + c];
        if (slot < 0 || g.range[i] < g.range[slot]) slot = static_cast<int>(i);
    }
}

// Divide: breadth-first growth inside each block of B columns, bridging empty pixels (gap
// rows, colGap columns). Labels per pixel (-1: empty); returns the number of labels.
int growInBlocks(const PixelGraph &g, std::vector<int> &label) {
    const int R = g.R, C = g.C, B = g.B;
    const int blocks = (C + B - 1) / B;
    label.assign(g.pix.size(), -1);
    int next_label = 0;
    std::deque<int> queue;
    for (int b = 0; b < blocks; ++b) {
        const int c0 = b * B, c1 = std::min(C, c0 + B);
        for (int r = 0; r < R; ++r) {
            for (int c = c0; c < c1; ++c) {
                const size_t seed = static_cast<size_t>(r) * C + c;
                if (g.pix[seed] < 0 || label[seed] >= 0) continue;
                label[seed] = next_label;
                queue.assign(1, static_cast<int>(seed));
                while (!queue.empty()) {
                    const int cur = queue.front();
                    queue.pop_front();
                    const int cr = cur / C, cc = cur % C;
                    const int dirs[4][2] = {{1, 0}, {-1, 0}, {0, 1}, {0, -1}};
                    const int hgap = g.colGap(cur);
                    for (const auto &d : dirs) {
                        const int max_step = (d[1] != 0 ? hgap : g.gap) + 1;
                        for (int step = 1; step <= max_step; ++step) {
                            const int nr = cr + d[0] * step, nc = cc + d[1] * step;
                            if (nr < 0 || nr >= R || nc < c0 || nc >= c1) break;
                            const size_t q = static_cast<size_t>(nr) * C + nc;
                            if (g.pix[q] < 0) continue;  // bridge empty pixels
                            if (label[q] < 0 && g.connected(g.pix[cur], g.pix[q])) {
                                label[q] = next_label;
                                queue.push_back(static_cast<int>(q));
                            }
                            break;  // the first occupied pixel is the neighbour
                        }
                    }
                }
                ++next_label;
            }
        }
    }
    return next_label;
}

// The first occupied pixel of row r from column `from` stepping by `dir`, at most gap steps and
// not past `limit`: its pixel index and steps taken, or -1.
int firstOccupied(const PixelGraph &g, int r, int from, int dir, int limit, int &steps) {
    for (int k = 0; k <= g.gap && (dir < 0 ? from - k >= limit : from + k <= limit); ++k) {
        const size_t q = static_cast<size_t>(r) * g.C + (from + dir * k);
        if (g.pix[q] >= 0) {
            steps = k;
            return static_cast<int>(q);
        }
    }
    return -1;
}

// Merge: the labels on either side of each block edge are united when enough row pairs across
// the edge connect (min_votes, fewer for labels with fewer pixels at the edge).
void mergeAcrossBlocks(const PixelGraph &g, const std::vector<int> &label, bool wrap,
                       UnionFind &uf) {
    const int C = g.C, B = g.B;
    const int blocks = (C + B - 1) / B;
    const int edges = wrap ? blocks : blocks - 1;
    for (int b = 0; b < edges && blocks > 1; ++b) {
        const int left_end = std::min(C, (b + 1) * B) - 1;
        const int right_start = (b + 1 == blocks) ? 0 : (b + 1) * B;
        const int right_end = (b + 1 == blocks) ? std::min(C, B) - 1 : std::min(C, (b + 2) * B) - 1;
        const int left_start = b * B;
        std::map<int, int> edge_count;
        std::map<std::pair<int, int>, int> votes;
        for (int r = 0; r < g.R; ++r) {
            int da = 0, db = 0;
            const int a = firstOccupied(g, r, left_end, -1, left_start, da);
            const int bb = firstOccupied(g, r, right_start, +1, right_end, db);
            if (a >= 0) edge_count[label[a]]++;
            if (bb >= 0) edge_count[label[bb]]++;
            if (a < 0 || bb < 0 || da + db > g.gap) continue;
            if (g.connected(g.pix[a], g.pix[bb])) votes[{label[a], label[bb]}]++;
        }
        for (const auto &[pair, v] : votes) {
            const int need =
                std::min({g.opt.min_votes, edge_count[pair.first], edge_count[pair.second]});
            if (v >= std::max(1, need)) uf.unite(pair.first, pair.second);
        }
    }
}

// Gather points: pixel representatives and the other points of their pixel nearby, by merged
// label; clusters of at least min_size points.
Clusters gatherClusters(const PixelGraph &g, const RangeImageProjection &proj,
                        const std::vector<int> &label, UnionFind &uf, int min_size) {
    std::map<int, std::vector<int>> groups;
    for (Eigen::Index i = 0; i < g.points.rows(); ++i) {
        const int r = proj.row[i], c = proj.col[i];
        if (r < 0 || c < 0) continue;
        const size_t q = static_cast<size_t>(r) * g.C + c;
        const int rep = g.pix[q];
        if (rep < 0 || label[q] < 0) continue;
        if (rep != i && (g.points.row(i) - g.points.row(rep)).norm() > g.opt.max_neighbour_gap_m)
            continue;
        groups[uf.find(label[q])].push_back(static_cast<int>(i));
    }
    Clusters out;
    for (auto &[root, rows] : groups) {
        (void)root;
        if (static_cast<int>(rows.size()) >= min_size) out.push_back(std::move(rows));
    }
    return out;
}

}  // namespace

Clusters rangeImageClusters(const Eigen::Ref<const Points3> &points,
                            const RangeImageProjection &proj, const SensorGeometry &s,
                            const SegmentationConfig &opt, int min_size) {
    const int R = s.image_rows, C = s.image_cols;
    if (R <= 0 || C <= 0 || points.rows() == 0) return {};
    const bool wrap = s.horizontal_fov_rad >= 2 * kPi - 1e-6;
    PixelGraph g{points,
                 opt,
                 R,
                 C,
                 std::max(0, opt.max_pixel_gap),
                 std::max(1, opt.block_cols),
                 s.horizontal_fov_rad / C,
                 {},
                 {}};
    nearestPerPixel(g, proj);
    std::vector<int> label;
    UnionFind uf(growInBlocks(g, label));
    mergeAcrossBlocks(g, label, wrap, uf);
    return gatherClusters(g, proj, label, uf, min_size);
}

Clusters euclideanClusters(const Eigen::Ref<const Points3> &points, double tolerance_m,
                           int min_size) {
    Clusters out;
    if (points.rows() == 0) return out;
    std::vector<int> rows(static_cast<size_t>(points.rows()));
    std::iota(rows.begin(), rows.end(), 0);
    auto cloud = subsetCloud(points, rows);
    pcl::search::KdTree<pcl::PointXYZ>::Ptr tree(new pcl::search::KdTree<pcl::PointXYZ>);
    tree->setInputCloud(cloud);
    std::vector<pcl::PointIndices> found;
    pcl::EuclideanClusterExtraction<pcl::PointXYZ> ec;
    ec.setClusterTolerance(tolerance_m);
    ec.setMinClusterSize(std::max(1, min_size));
    ec.setMaxClusterSize(std::numeric_limits<int>::max());
    ec.setSearchMethod(tree);
    ec.setInputCloud(cloud);
    ec.extract(found);
    for (const auto &c : found) out.emplace_back(c.indices.begin(), c.indices.end());
    return out;
}

double adaptiveEps(const Eigen::Ref<const Points3> &points, const std::vector<int> &rows,
                   double theta_v_rad, const SegmentationConfig &opt) {
    Eigen::Vector2d mean = Eigen::Vector2d::Zero();
    for (int i : rows) mean += points.block<1, 2>(i, 0).transpose();
    if (!rows.empty()) mean /= static_cast<double>(rows.size());
    const double eps = opt.dbscan_k * theta_v_rad * mean.norm();
    return std::clamp(eps, opt.dbscan_min_eps_m, opt.dbscan_max_eps_m);
}

Clusters dbscan(const Eigen::Ref<const Points3> &points, const std::vector<int> &rows, double eps,
                int min_neighbours) {
    Clusters out;
    const size_t n = rows.size();
    if (n == 0 || !(eps > 0)) return out;
    const double eps2 = eps * eps;
    // Neighbour lists (brute force for small clusters, KD-tree otherwise).
    std::vector<std::vector<int>> nb(n);
    if (n <= 256) {
        // The pairs first, then each list sized once (one allocation per list, not a growing
        // one); filled in pair order, so every list holds its rows ascending as before.
        std::vector<std::pair<int, int>> pairs;
        std::vector<int> degree(n, 0);
        for (size_t a = 0; a < n; ++a)
            for (size_t b = a + 1; b < n; ++b)
                if ((points.row(rows[a]) - points.row(rows[b])).squaredNorm() <= eps2) {
                    pairs.emplace_back(static_cast<int>(a), static_cast<int>(b));
                    ++degree[a], ++degree[b];
                }
        for (size_t a = 0; a < n; ++a) nb[a].reserve(static_cast<size_t>(degree[a]));
        for (const auto &[a, b] : pairs) nb[a].push_back(b), nb[b].push_back(a);
    } else {
        auto cloud = subsetCloud(points, rows);
        pcl::KdTreeFLANN<pcl::PointXYZ> tree;
        tree.setInputCloud(cloud);
        pcl::Indices idx;
        std::vector<float> d2;
        for (size_t a = 0; a < n; ++a) {
            tree.radiusSearch((*cloud)[a], eps, idx, d2);
            for (auto b : idx)
                if (static_cast<size_t>(b) != a) nb[a].push_back(static_cast<int>(b));
        }
    }
    std::vector<int> label(n, -1);
    int next = 0;
    for (size_t a = 0; a < n; ++a) {
        if (label[a] >= 0 || static_cast<int>(nb[a].size()) < min_neighbours) continue;
        label[a] = next;
        std::vector<int> stack{static_cast<int>(a)};
        std::vector<int> members{static_cast<int>(a)};
        while (!stack.empty()) {
            const int cur = stack.back();
            stack.pop_back();
            if (static_cast<int>(nb[cur].size()) < min_neighbours) continue;  // border point
            for (int q : nb[cur]) {
                if (label[q] >= 0) continue;
                label[q] = next;
                members.push_back(q);
                stack.push_back(q);
            }
        }
        std::vector<int> cluster;
        cluster.reserve(members.size());
        for (int m : members) cluster.push_back(rows[static_cast<size_t>(m)]);
        out.push_back(std::move(cluster));
        ++next;
    }
    return out;
}

}  // namespace forestslam::perception
