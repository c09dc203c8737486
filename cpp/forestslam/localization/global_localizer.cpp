#include "forestslam/localization/global_localizer.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <stdexcept>
#include <string>
#include <tuple>
#include <unordered_set>

#include "forestslam/common/voxel_key.hpp"

namespace forestslam::localization {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr int kMapTriangleNeighbours = 8;  // map triangles: each trunk with 2 of its 8 nearest
constexpr double kMaxTriangleEdge = 30.0;  // metres
constexpr int kMinStarsBeforeExit = 30;    // query stars tried before a decisive early exit
// Best-scoring hypotheses given the full test. The significance is corrected for every hypothesis
// searched (Bonferroni), so taking the most significant of more of them stays calibrated. In a
// sparse view (at most kSparseView scoring trunks) the true pose (4-5 inliers) is often outscored
// by chance poses (5-6), so 32 are tested there; in a larger view it stands out by its score,
// and 4 keep large queries fast (32 cost 20-30 % more CPU on 200-tree queries).
constexpr size_t kEvaluatedHypotheses = 4;
constexpr size_t kEvaluatedHypothesesSparse = 32;
constexpr Eigen::Index kSparseView = 50;
constexpr int kDbhNeighbours = 30;  // the DBH neighbourhood of a map trunk

double wrapAngle(double a) {
    a = std::fmod(a + kPi, 2 * kPi);
    if (a < 0) a += 2 * kPi;
    return a - kPi;
}

Eigen::Vector2d apply(const Eigen::Vector3d &pose, const Eigen::Vector2d &p) {
    const double c = std::cos(pose[2]), s = std::sin(pose[2]);
    return {c * p.x() - s * p.y() + pose[0], s * p.x() + c * p.y() + pose[1]};
}

// Local row -> map row, each map trunk used once (the closer local trunk wins).
std::vector<std::pair<int, int>> associate(const Points2 &local, const Eigen::Vector3d &pose,
                                           const PointGrid &grid, double gate,
                                           std::vector<double> *d2s = nullptr) {
    std::vector<std::tuple<int, int, double>> pairs;
    for (Eigen::Index i = 0; i < local.rows(); ++i) {
        const Eigen::Vector2d q = apply(pose, local.row(i).transpose());
        double d2 = 0;
        const int j = grid.nearest(q.x(), q.y(), gate, &d2);
        if (j >= 0) pairs.emplace_back(static_cast<int>(i), j, d2);
    }
    std::sort(pairs.begin(), pairs.end(), [](const auto &a, const auto &b) {
        return std::get<1>(a) != std::get<1>(b) ? std::get<1>(a) < std::get<1>(b)
                                                : std::get<2>(a) < std::get<2>(b);
    });
    std::vector<std::pair<int, int>> out;
    if (d2s) d2s->clear();
    for (size_t k = 0; k < pairs.size(); ++k) {
        if (k > 0 && std::get<1>(pairs[k]) == std::get<1>(pairs[k - 1])) continue;
        out.emplace_back(std::get<0>(pairs[k]), std::get<1>(pairs[k]));
        if (d2s) d2s->push_back(std::get<2>(pairs[k]));
    }
    return out;
}

// Consensus score only (cheap): local trunks landing within the gate of some map trunk.
int consensus(const Points2 &local, const Eigen::Vector3d &pose, const PointGrid &grid,
              double gate) {
    const double c = std::cos(pose[2]), s = std::sin(pose[2]);  // once, not per trunk
    int count = 0;
    for (Eigen::Index i = 0; i < local.rows(); ++i) {
        const double x = c * local(i, 0) - s * local(i, 1) + pose[0];
        const double y = s * local(i, 0) + c * local(i, 1) + pose[1];
        if (grid.nearest(x, y, gate) >= 0) ++count;
    }
    return count;
}

// How close the runner-up comes: its significance over the best's (same test, same trunks), 0
// without a runner-up or when it is no evidence at all. Significance, not the inlier count: in a
// 6-trunk view 4 inliers against 5 says nothing, in a 100-trunk view both are decisive.
double runnerUpFraction(double best_significance, const RunnerUp &r) {
    if (!r.exists || r.significance <= 0) return 0.0;
    return r.significance / std::max(best_significance, 1e-9);
}

// Vertex correspondence check of two stars: the nine edges agree in length and every triangle
// of the star has the same orientation on both sides (the side test). *deviation: the norm of
// the nine edge-length differences.
bool starsAgree(const Eigen::Ref<const Points2> &local, const Star &ls,
                const Eigen::Ref<const Points2> &map, const Star &ms, double tol,
                double *deviation) {
    auto L = [&](int k) { return Eigen::Vector2d(local.row(ls.vertices[k]).transpose()); };
    auto M = [&](int k) { return Eigen::Vector2d(map.row(ms.vertices[k]).transpose()); };
    static const int edges[9][2] = {{0, 1}, {1, 2}, {2, 0}, {0, 3}, {1, 3},
                                    {1, 4}, {2, 4}, {2, 5}, {0, 5}};
    double sq = 0;
    for (const auto &e : edges) {
        const double d = std::abs((L(e[0]) - L(e[1])).norm() - (M(e[0]) - M(e[1])).norm());
        if (d > tol) return false;
        sq += d * d;
    }
    *deviation = std::sqrt(sq);
    // Side test: the apex across edge (a, b) lies on the other side of it from the centre.
    static const int sides[4][3] = {{0, 1, 2}, {1, 0, 3}, {2, 1, 4}, {0, 2, 5}};
    for (const auto &s : sides) {
        const double ol = orient2d(L(s[0]), L(s[1]), L(s[2]));
        const double om = orient2d(M(s[0]), M(s[1]), M(s[2]));
        if (ol * om <= 0) return false;
    }
    return true;
}

// Rigid fit of corresponding points; false when any residual exceeds tol.
bool fitConsistent(const std::vector<Eigen::Vector2d> &a, const std::vector<Eigen::Vector2d> &b,
                   double tol, Eigen::Vector3d &pose) {
    pose = fitRigid2D(a, b);
    for (size_t k = 0; k < a.size(); ++k)
        if ((apply(pose, a[k]) - b[k]).norm() > tol) return false;
    return true;
}

// Starting edges worth trying for a local triangle: the shortest, and any edge that noise could
// make the shortest.
std::vector<int> rotationsToTry(const Triangulation &tri, const Eigen::Ref<const Points2> &xy,
                                int t, const GlobalLocalizerConfig &cfg) {
    const int r0 = shortestEdge(tri, xy, t);
    const double shortest = edgeLength(tri, xy, t, r0);
    std::vector<int> out = {r0};
    for (int dr = 1; dr < 3; ++dr) {
        const int r = (r0 + dr) % 3;
        if (edgeLength(tri, xy, t, r) <=
            shortest * (1 + cfg.rotation_ambiguity) + cfg.edge_tolerance_m)
            out.push_back(r);
    }
    return out;
}

// Rows of xy on the hull of tri (a vertex of an edge with no triangle across it).
std::vector<bool> hullFlags(const Triangulation &tri, Eigen::Index rows) {
    std::vector<bool> on_hull(rows, false);
    for (size_t t = 0; t < tri.size(); ++t)
        for (int k = 0; k < 3; ++k)
            if (tri.neighbours[t][k] < 0) {
                on_hull[tri.triangles[t][(k + 1) % 3]] = true;
                on_hull[tri.triangles[t][(k + 2) % 3]] = true;
            }
    return on_hull;
}

Points2 rowsOf(const Eigen::Ref<const Points2> &xy, const std::vector<int> &rows) {
    Points2 out(rows.size(), 2);
    for (size_t k = 0; k < rows.size(); ++k) out.row(k) = xy.row(rows[k]);
    return out;
}

// Stage 1's stars in the order they are tried: only stars among the scoring trunks (`near`),
// nearest first. The key does not depend on the input row order: farthest vertex, then the
// vertices' spread.
std::vector<int> starOrder(const Eigen::Ref<const Points2> &local,
                           const std::vector<int> &near_rows, const StarSet &lstars,
                           const std::vector<bool> &on_hull, bool skip_hull_stars) {
    std::vector<bool> near(local.rows(), false);
    for (int r : near_rows) near[r] = true;
    auto reach2 = [&](const Star &s) {
        double m = 0, sum = 0, sx = 0;
        for (int v : s.vertices) {
            m = std::max(m, local.row(v).squaredNorm());
            sum += local.row(v).squaredNorm();
            sx += local(v, 0);
        }
        return std::make_tuple(m, sum, sx);
    };
    std::vector<std::pair<std::tuple<double, double, double>, int>> order;
    for (size_t i = 0; i < lstars.stars.size(); ++i) {
        const Star &s = lstars.stars[i];
        bool inside = true, hull = false;
        for (int v : s.vertices) {
            inside = inside && near[v];
            hull = hull || on_hull[v];
        }
        if (!inside || (skip_hull_stars && hull)) continue;
        order.emplace_back(reach2(s), static_cast<int>(i));
    }
    std::sort(order.begin(), order.end());
    std::vector<int> out;
    out.reserve(order.size());
    for (const auto &o : order) out.push_back(o.second);
    return out;
}

// Stage 2's local triangles nearest first (most completely observed); the key does not depend
// on the input row order (ties broken by the vertices' spread).
void sortByReach(std::vector<std::array<int, 3>> &tris, const Eigen::Ref<const Points2> &local) {
    auto reach = [&](const std::array<int, 3> &t) {
        const double a = local.row(t[0]).squaredNorm(), b = local.row(t[1]).squaredNorm(),
                     c = local.row(t[2]).squaredNorm();
        return std::make_tuple(std::max({a, b, c}), a + b + c,
                               local(t[0], 0) + local(t[1], 0) + local(t[2], 0));
    };
    std::sort(tris.begin(), tris.end(),
              [&](const auto &a, const auto &b) { return reach(a) < reach(b); });
}

// Stage 2's local triangles in the order they are tried: each trunk with two of its nearest
// among the first max_fallback_trunks of `near_rows`, nearest first. When some trunks are not
// confirmed (seen in one aggregated frame only: a transient false detection is, and an
// aggregated view gathers one per frame while its true trunks saturate), the triangles of the
// confirmed trunks among themselves come first (a transient does not take a true neighbour's
// place), then the others.
std::vector<std::array<int, 3>> fallbackTriangles(const Eigen::Ref<const Points2> &local,
                                                  const std::vector<int> &near_rows,
                                                  const std::vector<bool> &confirmed,
                                                  const GlobalLocalizerConfig &cfg) {
    auto firstRows = [&](bool confirmed_only) {
        std::vector<int> rows;
        for (int r : near_rows) {
            if (cfg.max_fallback_trunks > 0 && int(rows.size()) >= cfg.max_fallback_trunks) break;
            if (!confirmed_only || confirmed[r]) rows.push_back(r);
        }
        return rows;
    };
    auto trianglesOf = [&](const std::vector<int> &rows) {
        std::vector<std::array<int, 3>> tris =
            neighbourTriangles(local, rows, cfg.triangle_neighbours, kMaxTriangleEdge);
        sortByReach(tris, local);
        return tris;
    };
    const std::vector<int> all = firstRows(false), sure = firstRows(true);
    // (neighbourTriangles takes every row when given none: fewer than 3 sure rows, one group.)
    if (sure == all || sure.size() < 3) return trianglesOf(all);
    std::vector<std::array<int, 3>> out = trianglesOf(sure);
    auto key = [](std::array<int, 3> t) {
        std::sort(t.begin(), t.end());
        return t;
    };
    std::vector<std::array<int, 3>> tried;
    for (const auto &t : out) tried.push_back(key(t));
    std::sort(tried.begin(), tried.end());
    for (const auto &t : trianglesOf(all))
        if (!std::binary_search(tried.begin(), tried.end(), key(t))) out.push_back(t);
    return out;
}

// Eq. 3: the candidate angles between corresponding centre edges of two stars (vertices in
// canonical order, Eq. 2); the one with the smallest squared vertex residual wins, the
// translation D is the centroid difference.
Eigen::Vector3d paperPose(const Eigen::Matrix<double, 6, 2> &L,
                          const Eigen::Matrix<double, 6, 2> &M) {
    const Eigen::Vector2d lc = L.colwise().mean(), mc = M.colwise().mean();
    double best_cost = std::numeric_limits<double>::infinity();
    Eigen::Vector3d pose;
    for (int e = 0; e < 3; ++e) {
        const Eigen::Vector2d dl = L.row((e + 1) % 3) - L.row(e);
        const Eigen::Vector2d dm = M.row((e + 1) % 3) - M.row(e);
        const double beta = wrapAngle(std::atan2(dm.y(), dm.x()) - std::atan2(dl.y(), dl.x()));
        const Eigen::Vector3d cand(0, 0, beta);
        const Eigen::Vector2d d = mc - apply(cand, lc);  // D = centroid difference
        double cost = 0;
        for (int k = 0; k < 6; ++k)
            cost += (apply(cand, L.row(k).transpose()) + d - M.row(k).transpose()).squaredNorm();
        if (cost < best_cost) {
            best_cost = cost;
            pose = {d.x(), d.y(), beta};
        }
    }
    return pose;
}

// Least-squares refinement of pose over all inliers, re-associating each round; *pairs: the
// inliers of the refined pose.
Eigen::Vector3d refinePose(const Points2 &local, const Points2 &map, const PointGrid &grid,
                           Eigen::Vector3d pose, const GlobalLocalizerConfig &cfg,
                           std::vector<std::pair<int, int>> *pairs) {
    for (int it = 0; it < std::max(1, cfg.refine_iterations); ++it) {
        *pairs = associate(local, pose, grid, cfg.inlier_gate_m);
        if (pairs->size() < 3) break;
        std::vector<Eigen::Vector2d> a, b;
        for (const auto &[i, j] : *pairs) {
            a.push_back(local.row(i).transpose());
            b.push_back(map.row(j).transpose());
        }
        const Eigen::Vector3d next = fitRigid2D(a, b);
        const bool converged =
            (next - pose).head<2>().norm() < 1e-9 && std::abs(wrapAngle(next[2] - pose[2])) < 1e-11;
        pose = next;
        if (converged) break;
    }
    *pairs = associate(local, pose, grid, cfg.inlier_gate_m);
    pose[2] = wrapAngle(pose[2]);
    return pose;
}

// res.rms_m and res.covariance = sigma^2 (J^T J)^-1 with r_i = R p_i + t - q_i over the pairs
// at res's pose.
void setCovariance(const Points2 &local, const Points2 &map,
                   const std::vector<std::pair<int, int>> &pairs, double min_sigma_m,
                   GlobalLocalization &res) {
    Eigen::Matrix3d JtJ = Eigen::Matrix3d::Zero();
    double sse = 0;
    const Eigen::Vector3d pose(res.x, res.y, res.yaw);
    const double c = std::cos(pose[2]), s = std::sin(pose[2]);
    for (const auto &[i, j] : pairs) {
        const Eigen::Vector2d p = local.row(i).transpose();
        const Eigen::Vector2d r = apply(pose, p) - map.row(j).transpose();
        sse += r.squaredNorm();
        Eigen::Matrix<double, 2, 3> J;
        J << 1, 0, -s * p.x() - c * p.y(), 0, 1, c * p.x() - s * p.y();
        JtJ += J.transpose() * J;
    }
    const int n = static_cast<int>(pairs.size());
    res.rms_m = n > 0 ? std::sqrt(sse / n) : 0.0;
    const double dof = std::max(1, 2 * n - 3);
    const double sigma2 = std::max(sse / dof, min_sigma_m * min_sigma_m);
    Eigen::FullPivLU<Eigen::Matrix3d> lu(JtJ);
    if (lu.isInvertible()) res.covariance = sigma2 * lu.inverse();
}

// The verdict of the acceptance test on res (its inliers set), the answer's evidence and the
// runner-up's fraction of it; `explainable` local trunks are expected to have a map trunk (the
// base of min_inlier_fraction).
void applyVerdict(const ChanceEvidence &best, double runner_fraction, int explainable,
                  const GlobalLocalizerConfig &cfg, GlobalLocalization &res) {
    res.significance = best.significance;
    res.expected_chance_inliers = best.expected;
    res.dbh_pairs = best.dbh_pairs;
    AcceptanceConfig acfg;
    acfg.min_significance = cfg.min_significance;
    acfg.ambiguity_ratio = cfg.ambiguity_ratio;
    const bool all_dbh = best.dbh_pairs >= best.inliers;
    acfg.min_inliers =
        all_dbh ? std::min(cfg.min_inliers, cfg.min_inliers_with_dbh) : cfg.min_inliers;
    const AcceptanceVerdict verdict = judge(best, runner_fraction, acfg);
    res.rejected = !verdict.accepted;
    res.reason = verdict.reason;
    if (verdict.accepted && res.inliers < cfg.min_inlier_fraction * explainable) {
        res.rejected = true;
        res.reason = "inlier fraction too low";
    }
}

}  // namespace

const char *stageName(LocalizationStage stage) {
    switch (stage) {
        case LocalizationStage::Star:
            return "star";
        case LocalizationStage::Triangle:
            return "triangle";
        default:
            return "";
    }
}

Eigen::Matrix3d GlobalLocalization::transform() const {
    Eigen::Matrix3d T = Eigen::Matrix3d::Identity();
    T(0, 0) = std::cos(yaw);
    T(0, 1) = -std::sin(yaw);
    T(1, 0) = std::sin(yaw);
    T(1, 1) = std::cos(yaw);
    T(0, 2) = x;
    T(1, 2) = y;
    return T;
}

Eigen::Vector3d fitRigid2D(const std::vector<Eigen::Vector2d> &local,
                           const std::vector<Eigen::Vector2d> &map) {
    if (local.size() != map.size())
        throw std::invalid_argument("fitRigid2D: " + std::to_string(local.size()) +
                                    " local points for " + std::to_string(map.size()) +
                                    " map points");
    const size_t n = local.size();
    if (n == 0) return Eigen::Vector3d::Zero();
    Eigen::Vector2d lc = Eigen::Vector2d::Zero(), mc = Eigen::Vector2d::Zero();
    for (size_t i = 0; i < n; ++i) {
        lc += local[i];
        mc += map[i];
    }
    lc /= double(n);
    mc /= double(n);
    double sxx = 0, sxy = 0;  // sum of dot and cross products of centred pairs
    for (size_t i = 0; i < n; ++i) {
        const Eigen::Vector2d p = local[i] - lc, q = map[i] - mc;
        sxx += p.dot(q);
        sxy += p.x() * q.y() - p.y() * q.x();
    }
    const double yaw = std::atan2(sxy, sxx);
    const double c = std::cos(yaw), s = std::sin(yaw);
    const Eigen::Vector2d t =
        mc - Eigen::Vector2d(c * lc.x() - s * lc.y(), s * lc.x() + c * lc.y());
    return {t.x(), t.y(), yaw};
}

TreeMap::TreeMap(const Eigen::Ref<const Points2> &xy, double duplicate_tolerance_m,
                 const Eigen::VectorXd &dbh)
    : xy_(xy) {
    if (dbh.size() != 0 && dbh.size() != xy.rows())
        throw std::invalid_argument("TreeMap: " + std::to_string(dbh.size()) + " DBH values for " +
                                    std::to_string(xy.rows()) + " trees");
    tri_ = delaunayTriangulation(xy_, duplicate_tolerance_m);
    stars_ = buildStars(tri_, xy_);
    KdTree::Matrix feats(stars_.stars.size(), 8);
    for (size_t i = 0; i < stars_.stars.size(); ++i)
        feats.row(i) = embedFeature(stars_.stars[i].feature).transpose();
    index_ = KdTree(std::move(feats));
    triplets_ = neighbourTriangles(xy_, tri_.used_points, kMapTriangleNeighbours, kMaxTriangleEdge);
    KdTree::Matrix sides(triplets_.size(), 3);
    for (size_t t = 0; t < triplets_.size(); ++t)
        sides.row(t) = triangleSides(xy_, triplets_[t]).transpose();
    triangle_index_ = KdTree(std::move(sides));
    grid_ = PointGrid(xy_, 1.0);
    density_ = DensityGrid(xy_);
    buildDbhNeighbourhoods(dbh);
}

void TreeMap::buildDbhNeighbourhoods(const Eigen::VectorXd &dbh) {
    std::vector<int> rows;  // trees with a usable DBH
    for (Eigen::Index i = 0; i < dbh.size(); ++i)
        if (std::isfinite(dbh[i]) && dbh[i] > 0 && std::isfinite(xy_(i, 0)) &&
            std::isfinite(xy_(i, 1)))
            rows.push_back(static_cast<int>(i));
    if (static_cast<int>(rows.size()) < kDbhNeighbours) return;  // too few to tell chance
    dbh_ = dbh;
    KdTree::Matrix pts(rows.size(), 2);
    for (size_t k = 0; k < rows.size(); ++k) pts.row(k) = xy_.row(rows[k]);
    const KdTree tree(std::move(pts));
    dbh_neighbours_.assign(xy_.rows(), {});
    std::vector<int> idx;
    std::vector<double> dist;
    for (int r : rows) {
        tree.knn(xy_.row(r).transpose(), kDbhNeighbours, std::numeric_limits<double>::infinity(),
                 idx, dist);
        auto &nb = dbh_neighbours_[r];
        for (int k : idx) nb.push_back(static_cast<float>(dbh[rows[k]]));
        std::sort(nb.begin(), nb.end());
    }
}

double TreeMap::dbhAgreement(int j, double local_dbh, const GlobalLocalizerConfig &cfg) const {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    if (!hasDbh() || !std::isfinite(local_dbh) || local_dbh <= 0) return nan;
    const auto &nb = dbh_neighbours_[j];
    if (nb.empty()) return nan;  // this map trunk has no DBH
    // Under a chance match map trunk j is any of its neighbourhood (which holds j itself).
    return dbhLogRatio(local_dbh, dbh_[j], nb, cfg.dbh_sigma_m, cfg.dbh_outlier_fraction);
}

// Verified hypotheses; poses that fall in the same small cell are verified once.
struct TreeMap::Hypotheses {
    std::vector<Hypothesis> list;
    std::unordered_set<uint64_t> seen;

    int best = 0;      // highest consensus so far
    int verified = 0;  // every verified correspondence, duplicates included (time budget)
    std::vector<Eigen::Vector3d> matches;  // the pose of every verified correspondence

    void add(const Eigen::Vector3d &pose, const Points2 &local, const PointGrid &grid, double gate,
             LocalizationStage stage, double seed_evidence) {
        ++verified;
        matches.push_back(pose);
        const auto qx = static_cast<int64_t>(std::floor(pose[0] / 0.25));
        const auto qy = static_cast<int64_t>(std::floor(pose[1] / 0.25));
        const auto qa = static_cast<int64_t>(std::floor(wrapAngle(pose[2]) / 0.01));
        const uint64_t h = cellKey3(qx, qy, qa);
        if (!seen.insert(h).second) return;
        list.push_back({pose, consensus(local, pose, grid, gate), stage, seed_evidence});
        best = std::max(best, list.back().score);
    }
};

// The local trunks as the matchers use them.
struct TreeMap::Query {
    // with_dbh: both sides have DBH and the test uses it (scoring_dbh filled).
    Query(const Eigen::Ref<const Points2> &local_in, const GlobalLocalizerConfig &cfg,
          const Eigen::VectorXd &local_dbh, bool with_dbh, const Eigen::VectorXi &observations)
        : input(local_in), tri(delaunayTriangulation(local_in, cfg.duplicate_tolerance_m)) {
        usable = rowsOf(input, tri.used_points);
        // Without observation counts every trunk counts as confirmed (one order, as before).
        confirmed.assign(input.rows(), true);
        for (Eigen::Index i = 0; i < observations.size(); ++i) confirmed[i] = observations[i] >= 2;
        // The trunks a true pose should explain: in an aggregated view the confirmed ones (not
        // the transient detections it gathers, one set per frame); all in a single frame.
        explainable = 0;
        for (int r : tri.used_points) explainable += confirmed[r];
        if (explainable == 0) explainable = static_cast<int>(usable.rows());
        // Bounded work on huge local sets: hypotheses are scored on (and the fallback triangles
        // built from) the trunks nearest the local origin, where the view is most complete.
        near_rows = tri.used_points;
        std::sort(near_rows.begin(), near_rows.end(), [&](int a, int b) {
            return input.row(a).squaredNorm() < input.row(b).squaredNorm();
        });
        if (cfg.max_query_trunks > 0 && int(near_rows.size()) > cfg.max_query_trunks)
            near_rows.resize(cfg.max_query_trunks);
        scoring = rowsOf(input, near_rows);
        if (!with_dbh) return;
        scoring_dbh.resize(near_rows.size());
        for (size_t k = 0; k < near_rows.size(); ++k) scoring_dbh[k] = local_dbh[near_rows[k]];
    }

    Eigen::Ref<const Points2> input;  // as given (may hold non-finite rows and duplicates)
    Triangulation tri;                // of the usable trunks (rows of input)
    Points2 usable;                   // finite, de-duplicated trunks (the rows tri kept)
    std::vector<int> near_rows;       // rows of input nearest the origin (max_query_trunks)
    Points2 scoring;                  // those rows: the hypotheses are scored on them
    Eigen::VectorXd scoring_dbh;      // their diameters; empty unless with_dbh
    std::vector<bool> confirmed;      // per input row: seen in >= 2 frames (or no counts given)
    int explainable = 0;              // usable trunks confirmed (all when none is)
};

GlobalLocalization TreeMap::localize(const Eigen::Ref<const Points2> &local_in,
                                     const GlobalLocalizerConfig &cfg,
                                     const Eigen::VectorXd &local_dbh,
                                     const Eigen::VectorXi &observations) const {
    auto checkLength = [&](Eigen::Index n, const char *what) {
        if (n != 0 && n != local_in.rows())
            throw std::invalid_argument("localize: " + std::to_string(n) + " " + what + " for " +
                                        std::to_string(local_in.rows()) + " local trunks");
    };
    checkLength(local_dbh.size(), "DBH values");
    checkLength(observations.size(), "observation counts");
    const Query q(local_in, cfg, local_dbh, cfg.dbh_evidence && hasDbh() && local_dbh.size() != 0,
                  observations);
    GlobalLocalization res;
    res.local_trunks = static_cast<int>(q.usable.rows());
    if (q.tri.size() == 0) {
        res.reason = local_in.rows() < 3 ? "fewer than 3 trunks"
                                         : "fewer than 3 distinct, non-collinear trunks";
        return res;
    }
    if (tri_.size() == 0) {
        res.reason = "map has no triangles";
        return res;
    }
    if (cfg.matcher == Matcher::Paper) return localizePaper(res, q, cfg);
    return localizeDefault(res, q, cfg);
}

GlobalLocalization TreeMap::localizeDefault(const GlobalLocalization &base, const Query &q,
                                            const GlobalLocalizerConfig &cfg) const {
    GlobalLocalization res = base;
    Hypotheses hyps;
    // Early exit once a pose explains most trunks (bounded time on large local sets).
    const int decisive = std::max(2 * cfg.min_inliers, int(std::ceil(0.6 * q.scoring.rows())));
    res.query_stars = starHypotheses(q, cfg, decisive, hyps);
    res.hypotheses = static_cast<int>(hyps.list.size());
    GlobalLocalization stage1 = decide(res, hyps.list, res.hypotheses, q, cfg);
    stage1.matched_triangles = agreeing(hyps.matches, stage1, cfg);
    if (!stage1.rejected || !cfg.triangle_fallback) {
        if (stage1.rejected && hyps.list.empty())
            stage1.reason = res.query_stars == 0 ? "no interior triangles in the local trunks"
                                                 : "no matching triangle star in the map";
        return stage1;
    }
    // Stage 2 (fallback when missed or false trunks broke every star), held to the same test.
    if (triplets_.empty() || q.tri.used_points.size() < 3) return stage1;
    triangleHypotheses(q, cfg, decisive, hyps);
    res.hypotheses = static_cast<int>(hyps.list.size());
    GlobalLocalization stage2 = decide(res, hyps.list, res.hypotheses, q, cfg);
    if (stage2.rejected && hyps.list.empty()) stage2.reason = "no matching triangle in the map";
    stage2.matched_triangles = agreeing(hyps.matches, stage2, cfg);
    return stage2;
}

int TreeMap::starHypotheses(const Query &q, const GlobalLocalizerConfig &cfg, int decisive,
                            Hypotheses &hyps) const {
    const StarSet lstars = buildStars(q.tri, q.input);
    const std::vector<bool> on_hull = hullFlags(q.tri, q.input.rows());
    // Stop once a pose explains most trunks, after kMinStarsBeforeExit stars (so that a close
    // runner-up still has its chance to be found).
    int query_stars = 0;
    Star star;
    for (int si : starOrder(q.input, q.near_rows, lstars, on_hull, cfg.skip_hull_stars)) {
        if (query_stars >= kMinStarsBeforeExit && hyps.best >= decisive) break;
        ++query_stars;
        const int centre = lstars.stars[si].centre;
        for (int r : rotationsToTry(q.tri, q.input, centre, cfg)) {
            makeStar(q.tri, q.input, lstars.descriptors, centre, r, star);
            if (stars_.stars.empty()) break;
            matchStar(q, star, cfg, hyps);
        }
    }
    return query_stars;
}

void TreeMap::matchStar(const Query &q, const Star &star, const GlobalLocalizerConfig &cfg,
                        Hypotheses &hyps) const {
    std::vector<int> idx;
    std::vector<double> dist;
    index_.knn(embedFeature(star.feature), cfg.candidates_per_star, cfg.max_feature_distance_m, idx,
               dist);
    // All k returned: the nearest stars in feature space were kept, chance matches are no
    // longer spread over the whole tolerance; their edges are not tested for it.
    const bool saturated = int(idx.size()) >= cfg.candidates_per_star;
    std::vector<Eigen::Vector2d> lp(6), mp(6);
    Eigen::Vector3d pose;
    for (int m : idx) {
        const Star &ms = stars_.stars[m];
        double deviation = 0;
        if (!starsAgree(q.input, star, xy_, ms, cfg.edge_tolerance_m, &deviation)) continue;
        for (int k = 0; k < 6; ++k) {
            lp[k] = q.input.row(star.vertices[k]).transpose();
            mp[k] = xy_.row(ms.vertices[k]).transpose();
        }
        const double seed =
            cfg.seed_evidence && !saturated
                ? seedEvidence(deviation, cfg.edge_tolerance_m, 9, 2 * cfg.min_sigma_m)
                : 0.0;
        if (fitConsistent(lp, mp, cfg.edge_tolerance_m, pose))
            hyps.add(pose, q.scoring, grid_, cfg.inlier_gate_m, LocalizationStage::Star, seed);
    }
}

void TreeMap::triangleHypotheses(const Query &q, const GlobalLocalizerConfig &cfg, int decisive,
                                 Hypotheses &hyps) const {
    const std::vector<std::array<int, 3>> ltris =
        fallbackTriangles(q.input, q.near_rows, q.confirmed, cfg);
    // Bounded time where nothing matches (an absent place in a dense map verifies thousands of
    // chance triangle matches): at most max_fallback_matches, nearest triangles first.
    const int budget = hyps.verified + std::max(0, cfg.max_fallback_matches);
    for (const auto &t : ltris) {
        if (hyps.best >= decisive || hyps.verified >= budget) break;
        matchTriangle(q, t, cfg, hyps);
    }
}

void TreeMap::matchTriangle(const Query &q, const std::array<int, 3> &t,
                            const GlobalLocalizerConfig &cfg, Hypotheses &hyps) const {
    const double tol = cfg.edge_tolerance_m;
    std::vector<int> idx;
    std::vector<double> dist;
    std::vector<Eigen::Vector2d> lp(3), mp(3);
    Eigen::Vector3d pose;
    const Eigen::Vector3d s0 = triangleSides(q.input, t);
    for (int r = 0; r < 3; ++r) {
        const Eigen::Vector3d e = triangleSides(q.input, t, r);
        if (r > 0 && e[0] > s0[0] * (1 + cfg.rotation_ambiguity) + tol) continue;
        triangle_index_.knn(e, cfg.candidates_per_triangle, std::sqrt(3.0) * tol, idx, dist);
        // The side differences searched: within tol each (a cube: the search radius is its
        // corner's), or within the k-th neighbour's distance when all k were returned (a dense
        // map: only the nearest were kept; a ball, inside the cube when below tol).
        const bool saturated = int(idx.size()) >= cfg.candidates_per_triangle;
        const double radius = saturated ? std::min(tol, dist.back()) : tol;
        auto seedOf = [&](double deviation) {
            if (!cfg.seed_evidence) return 0.0;
            return saturated ? seedEvidence(deviation, radius, 3, 2 * cfg.min_sigma_m)
                             : seedEvidenceCube(deviation, tol, 3, 2 * cfg.min_sigma_m);
        };
        for (int m : idx) {
            const auto &mt = triplets_[m];
            const Eigen::Vector3d diff = triangleSides(xy_, mt) - e;
            if (diff.cwiseAbs().maxCoeff() > tol) continue;
            for (int k = 0; k < 3; ++k) {
                lp[k] = q.input.row(t[(r + k) % 3]).transpose();
                mp[k] = xy_.row(mt[k]).transpose();
            }
            if (fitConsistent(lp, mp, tol, pose))
                hyps.add(pose, q.scoring, grid_, cfg.inlier_gate_m, LocalizationStage::Triangle,
                         seedOf(diff.norm()));
        }
    }
}

GlobalLocalization TreeMap::localizePaper(GlobalLocalization res, const Query &q,
                                          const GlobalLocalizerConfig &cfg) const {
    std::vector<Hypothesis> hyps = paperHypotheses(q, cfg, res.query_stars);
    res.hypotheses = static_cast<int>(hyps.size());
    const int searched = static_cast<int>(hyps.size());  // the bins tested
    GlobalLocalization out = decide(res, hyps, searched, q, cfg);
    out.matched_triangles = hyps.empty() ? 0 : hyps.front().score;
    if (out.rejected && hyps.empty())
        out.reason = res.query_stars == 0 ? "no interior non-peripheral triangle star"
                                          : "no matching triangle star in the map";
    return out;
}

std::vector<Hypothesis> TreeMap::paperHypotheses(const Query &q, const GlobalLocalizerConfig &cfg,
                                                 int &query_stars) const {
    // Eq. 4's accumulator: (beta, Dx, Dy) bin -> votes and the sum of the voting poses.
    struct Bin {
        int votes = 0;
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        double c = 0, s = 0;  // summed rotation (angles average on the circle)
    };
    std::unordered_map<uint64_t, Bin> bins;
    const std::vector<bool> on_hull = hullFlags(q.tri, q.input.rows());
    const StarSet lstars = buildStars(q.tri, q.input);
    std::vector<int> idx;
    std::vector<double> dist;
    Eigen::Matrix<double, 6, 2> L, M;
    for (const Star &star : lstars.stars) {
        bool peripheral = false;
        for (int v : star.vertices) peripheral = peripheral || on_hull[v];
        if (peripheral || stars_.stars.empty()) continue;
        ++query_stars;
        index_.knn(embedFeature(star.feature), cfg.candidates_per_star, cfg.max_feature_distance_m,
                   idx, dist);
        for (int m : idx) {
            const Star &ms = stars_.stars[m];
            for (int k = 0; k < 6; ++k) {  // Eq. 2: vertices correspond in canonical order
                L.row(k) = q.input.row(star.vertices[k]);
                M.row(k) = xy_.row(ms.vertices[k]);
            }
            const Eigen::Vector3d pose = paperPose(L, M);
            const uint64_t key =
                cellKey3(static_cast<int64_t>(std::floor(pose[2] / cfg.paper_angle_bin_rad)),
                         static_cast<int64_t>(std::floor(pose[0] / cfg.paper_translation_bin_m)),
                         static_cast<int64_t>(std::floor(pose[1] / cfg.paper_translation_bin_m)));
            Bin &b = bins[key];
            ++b.votes;
            b.sum.head<2>() += pose.head<2>();
            b.c += std::cos(pose[2]);
            b.s += std::sin(pose[2]);
        }
    }
    // Every bin is a hypothesis scored by its votes (matched triangles); decide() refines the
    // fullest and applies the acceptance test, the runner-up being the next distinct bin.
    std::vector<Hypothesis> hyps;
    hyps.reserve(bins.size());
    for (const auto &[key, b] : bins) {
        const Eigen::Vector3d pose(b.sum.x() / b.votes, b.sum.y() / b.votes, std::atan2(b.s, b.c));
        hyps.push_back({pose, b.votes, LocalizationStage::Star});
    }
    // Deterministic order before the stable sort by votes (the map's bin order is not).
    std::sort(hyps.begin(), hyps.end(), [](const Hypothesis &a, const Hypothesis &b) {
        return std::make_tuple(a.pose[0], a.pose[1], a.pose[2]) <
               std::make_tuple(b.pose[0], b.pose[1], b.pose[2]);
    });
    return hyps;
}

int TreeMap::agreeing(const std::vector<Eigen::Vector3d> &matches, const GlobalLocalization &res,
                      const GlobalLocalizerConfig &cfg) const {
    if (res.stage == LocalizationStage::None) return 0;
    int n = 0;
    for (const auto &p : matches)
        n += (p.head<2>() - Eigen::Vector2d(res.x, res.y)).norm() <= cfg.distinct_translation_m &&
             std::abs(wrapAngle(p[2] - res.yaw)) <= cfg.distinct_yaw_rad;
    return n;
}

ChanceEvidence TreeMap::evidence(const Points2 &scoring, const Eigen::VectorXd &scoring_dbh,
                                 const Eigen::Vector3d &pose, int seeds, int searched,
                                 double seed_evidence, const GlobalLocalizerConfig &cfg) const {
    // Inliers one-to-one (two detections of a split stem near one map trunk are one).
    std::vector<double> d2s;
    const auto pairs = associate(scoring, pose, grid_, cfg.inlier_gate_m, &d2s);
    double closeness_sum = -1.0;
    if (cfg.closeness_evidence) {
        // Each inlier's distance under the pose fitted to the other inliers (leave-one-out):
        // independent of where it landed by chance, and free of the seed pose's lever-arm
        // error on far trunks (measured by the area of its error ellipse, acceptance.hpp).
        const std::vector<double> loo = leaveOneOutRadii(scoring, xy_, pairs);
        std::vector<double> close;
        close.reserve(pairs.size());
        for (size_t k = 0; k < pairs.size(); ++k) {
            const Eigen::Vector2d q = apply(pose, scoring.row(pairs[k].first).transpose());
            const double d = loo.empty() ? std::sqrt(d2s[k]) : loo[k];
            close.push_back(
                closeness(density_.at(q.x(), q.y()), d, cfg.inlier_gate_m, cfg.min_sigma_m));
        }
        // The seeds lie close by construction: the `seeds` closest inliers carry no evidence
        // (not the seed trunks themselves: under a chance pose their residuals from the other
        // inliers' fit need not be the smallest, and dropping the closest stays conservative
        // where real maps are not Poisson; Wild-Places absent places 8/2959 accepted with the
        // seed trunks left out, 1/2959 with the closest).
        std::sort(close.begin(), close.end(), std::greater<>());
        closeness_sum = 0.0;
        for (size_t k = std::min<size_t>(std::max(0, seeds), close.size()); k < close.size(); ++k)
            closeness_sum += close[k];
    }
    // DBH agreement of every inlier pair, seeds included (they were chosen by position only).
    double dbh_sum = 0.0;
    int dbh_pairs = 0;
    for (size_t k = 0; scoring_dbh.size() != 0 && k < pairs.size(); ++k) {
        const double a = dbhAgreement(pairs[k].second, scoring_dbh[pairs[k].first], cfg);
        if (std::isnan(a)) continue;
        dbh_sum += a;
        ++dbh_pairs;
    }
    ChanceEvidence e =
        chanceEvidence(static_cast<int>(pairs.size()), static_cast<int>(scoring.rows()),
                       expectedChance(scoring, pose, cfg.inlier_gate_m), seeds, searched,
                       closeness_sum, seed_evidence, dbh_pairs > 0 ? dbhEvidence(dbh_sum) : 0.0);
    e.dbh_pairs = dbh_pairs;
    return e;
}

double TreeMap::expectedChance(const Points2 &local, const Eigen::Vector3d &pose,
                               double gate) const {
    double sum = 0;
    for (Eigen::Index i = 0; i < local.rows(); ++i) {
        const Eigen::Vector2d q = apply(pose, local.row(i).transpose());
        sum += chanceRate(density_.at(q.x(), q.y()), gate);
    }
    return sum;
}

// The answer and the runner-up among the hypotheses, with their evidence.
struct TreeMap::Selection {
    size_t best = 0;
    ChanceEvidence best_evidence;
    int runner = -1;  // -1: none distinct
    ChanceEvidence runner_evidence;
};

TreeMap::Selection TreeMap::select(std::vector<Hypothesis> &hyps, int searched, const Query &q,
                                   const GlobalLocalizerConfig &cfg) const {
    // Stable: among equal scores the star hypotheses (found first) win.
    std::stable_sort(hyps.begin(), hyps.end(),
                     [](const Hypothesis &a, const Hypothesis &b) { return a.score > b.score; });
    // The test is made at a hypothesis' own pose, fixed by its seed points (the refinement
    // moves the pose to gather inliers, which chance alignments in a dense map also gain).
    // The most significant of the best-scoring few wins (in a sparse view several score alike
    // and only the closeness of the fit tells them apart; paper: the fullest bin); the runner-up is
    // the most significant distinct one of them, else the best-scoring distinct hypothesis.
    auto seeds = [](LocalizationStage s) { return s == LocalizationStage::Star ? 6 : 3; };
    auto evidenceOf = [&](const Hypothesis &h) {
        return evidence(q.scoring, q.scoring_dbh, h.pose, seeds(h.stage), searched, h.seed_evidence,
                        cfg);
    };
    std::vector<ChanceEvidence> top;
    const size_t evaluated =
        q.scoring.rows() <= kSparseView ? kEvaluatedHypothesesSparse : kEvaluatedHypotheses;
    for (size_t i = 0; i < std::min(evaluated, hyps.size()); ++i)
        top.push_back(evidenceOf(hyps[i]));
    Selection sel;
    for (size_t i = 1; cfg.matcher != Matcher::Paper && i < top.size(); ++i)
        if (top[i].significance > top[sel.best].significance) sel.best = i;
    sel.best_evidence = top[sel.best];
    const Eigen::Vector3d best = hyps[sel.best].pose;
    auto distinct = [&](const Hypothesis &h) {
        return (h.pose.head<2>() - best.head<2>()).norm() > cfg.distinct_translation_m ||
               std::abs(wrapAngle(h.pose[2] - best[2])) > cfg.distinct_yaw_rad;
    };
    for (size_t i = 0; i < top.size(); ++i)
        if (distinct(hyps[i]) &&
            (sel.runner < 0 || top[i].significance > sel.runner_evidence.significance)) {
            sel.runner = static_cast<int>(i);
            sel.runner_evidence = top[i];
        }
    for (size_t i = top.size(); sel.runner < 0 && i < hyps.size(); ++i)
        if (distinct(hyps[i])) {
            sel.runner = static_cast<int>(i);
            sel.runner_evidence = evidenceOf(hyps[i]);
        }
    return sel;
}

GlobalLocalization TreeMap::decide(const GlobalLocalization &base, std::vector<Hypothesis> &hyps,
                                   int searched, const Query &q,
                                   const GlobalLocalizerConfig &cfg) const {
    GlobalLocalization res = base;
    if (hyps.empty()) {
        res.reason = "no hypothesis";
        return res;
    }
    const Selection sel = select(hyps, searched, q, cfg);
    const Hypothesis best = hyps[sel.best];
    res.stage = best.stage;
    res.runner_up = RunnerUp{};
    res.second_inliers = 0;
    if (sel.runner >= 0) {
        RunnerUp &r = res.runner_up;
        r.exists = true;
        r.x = hyps[sel.runner].pose[0];
        r.y = hyps[sel.runner].pose[1];
        r.yaw = wrapAngle(hyps[sel.runner].pose[2]);
        r.inliers = sel.runner_evidence.inliers;
        r.significance = sel.runner_evidence.significance;
        res.second_inliers = r.inliers;
    }

    std::vector<std::pair<int, int>> pairs;
    const Eigen::Vector3d pose = refinePose(q.usable, xy_, grid_, best.pose, cfg, &pairs);
    res.x = pose[0];
    res.y = pose[1];
    res.yaw = pose[2];
    res.inliers = static_cast<int>(pairs.size());
    res.matches.clear();
    for (const auto &[i, j] : pairs) res.matches.emplace_back(q.tri.used_points[i], j);
    setCovariance(q.usable, xy_, pairs, cfg.min_sigma_m, res);

    // Paper: the runner-up bin's votes over the fullest's (the matcher's own score); its bins
    // are coarse (0.5 m, 2 deg), so a place split over two bins stays ambiguous.
    const double runner_fraction =
        cfg.matcher == Matcher::Paper
            ? (sel.runner >= 0 ? double(hyps[sel.runner].score) / std::max(best.score, 1) : 0.0)
            : runnerUpFraction(sel.best_evidence.significance, res.runner_up);
    applyVerdict(sel.best_evidence, runner_fraction, q.explainable, cfg, res);
    return res;
}

}  // namespace forestslam::localization
