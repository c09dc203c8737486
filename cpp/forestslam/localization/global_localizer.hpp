// Global localization of a set of locally observed trunks in a prior tree map by matching
// Delaunay triangle stars (Li et al., "Localization in Unstructured Environments: Towards
// Autonomous Robots in Forests with Delaunay Triangulation").
#pragma once

#include <array>
#include <string>
#include <utility>
#include <vector>

#include "forestslam/common/types.hpp"
#include "forestslam/localization/acceptance.hpp"
#include "forestslam/localization/delaunay.hpp"
#include "forestslam/localization/feature_index.hpp"
#include "forestslam/localization/triangle_star.hpp"

namespace forestslam::localization {

// Default: stars verified by edge lengths and the side test, least-squares pose per star match,
// consensus scoring. Paper: Li et al. as written (see localizePaper).
enum class Matcher { Default, Paper };

struct GlobalLocalizerConfig {
    Matcher matcher = Matcher::Default;
    int candidates_per_star = 8;          // k nearest map stars per query star
    double max_feature_distance_m = 1.5;  // in the embedded (sqrt) feature space
    double rotation_ambiguity = 0.15;  // also try starting edges this much longer than the shortest
    double edge_tolerance_m = 0.35;    // |local - map| for the nine star edges
    double inlier_gate_m = 0.5;        // local trunk within this of a map trunk: consensus
    int min_inliers = 4;               // fewer: rejected (the significance test decides)
    // The floor when every inlier has a DBH on both sides: a triangle's shape and three DBH
    // agreements can be significant (the test decides), three positions alone cannot.
    int min_inliers_with_dbh = 3;
    double min_inlier_fraction = 0.25;  // of the local trunks
    // Rejected when a distinct runner-up's significance reaches this fraction of the best's.
    double ambiguity_ratio = 0.8;
    double min_significance = 2.3;  // -log10 of the search-corrected chance probability (0.005)
    // Test how close the inliers land too (truncated product, see acceptance.hpp); residuals
    // below min_sigma_m count as min_sigma_m.
    bool closeness_evidence = true;
    // Test how closely the seed shape (star edges, triangle sides) matches its map shape too:
    // a chance match anywhere within edge_tolerance_m, a true one within the noise (see
    // acceptance.hpp); edge differences below 2 min_sigma_m count as 2 min_sigma_m.
    bool seed_evidence = true;
    // When the map and the query both have stem diameters: weigh each inlier's DBH agreement
    // by its likelihood ratio against the DBHs of the map trunk's neighbourhood
    // (acceptance.hpp): dbh_sigma_m the sigma of a true pair's DBH difference (query and map
    // errors), dbh_outlier_fraction the share of grossly wrong DBHs.
    bool dbh_evidence = true;
    double dbh_sigma_m = 0.03;
    double dbh_outlier_fraction = 0.1;
    double distinct_translation_m = 1.0;  // hypotheses further apart than this are distinct
    double distinct_yaw_rad = 0.0873;     // 5 deg
    int refine_iterations = 5;
    double min_sigma_m = 0.02;            // floor of the residual sigma in the covariance
    double duplicate_tolerance_m = 0.01;  // local trunks closer than this are one trunk
    bool skip_hull_stars = false;         // drop query stars with a vertex on the local hull
    // Single-triangle matching when no star hypothesis wins; its answers carry stage Triangle
    // and pass the same significance test (seeded by 3 points instead of 6).
    bool triangle_fallback = true;
    int candidates_per_triangle = 16;  // k nearest map triangles per local triangle (fallback)
    int triangle_neighbours = 5;       // local triangles: each trunk with 2 of its k nearest
    int max_query_trunks = 100;        // hypotheses scored on this many trunks nearest the origin
    int max_fallback_trunks = 40;      // fallback triangles from this many nearest trunks
    int max_fallback_matches = 500;    // verified triangle matches at most (time bound)
    // Paper matcher: bins of the (beta, Dx, Dy) vote of Eq. 4.
    double paper_angle_bin_rad = 0.0349;  // 2 deg
    double paper_translation_bin_m = 0.5;
};

enum class LocalizationStage { None, Star, Triangle };
const char *stageName(LocalizationStage stage);  // "", "star", "triangle"

struct Hypothesis {
    Eigen::Vector3d pose;  // x, y, yaw of T_map_local
    int score = 0;         // consensus: local trunks within the gate of a map trunk
    LocalizationStage stage = LocalizationStage::Star;
    double seed_evidence = 0.0;  // of the seed match's shape agreement, nats (acceptance.hpp)
};

// The best hypothesis distinct from the answer (further than distinct_translation_m or
// distinct_yaw_rad), scored on the same trunks.
struct RunnerUp {
    bool exists = false;
    double x = 0, y = 0, yaw = 0;
    int inliers = 0;            // consensus on the scoring trunks
    double significance = 0.0;  // same test as the answer's
};

struct GlobalLocalization {
    bool rejected = true;
    std::string reason;
    // T_map_local: map = R(yaw) * local + (x, y).
    double x = 0, y = 0, yaw = 0;
    Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity() * 1e6;  // x, y, yaw
    int inliers = 0;
    int second_inliers = 0;  // consensus of the best distinct alternative (= runner_up.inliers)
    // Which matcher produced the answer (None: no hypothesis).
    LocalizationStage stage = LocalizationStage::None;
    // -log10 of the probability that the inliers arise by chance at the map's local density,
    // corrected for the number of hypotheses searched (see acceptance.hpp); >= min_significance
    // to be accepted.
    double significance = 0.0;
    double expected_chance_inliers = 0.0;  // chance inliers expected beyond the seed points
    int dbh_pairs = 0;  // inliers of the tested pose with a DBH on both sides (DBH evidence)
    RunnerUp runner_up;
    int hypotheses = 0;  // verified distinct-by-hash hypotheses
    int query_stars = 0;
    // Star (triangle) matches whose pose agrees with the answer (within the distinct
    // thresholds): Li et al.'s "matched triangles".
    int matched_triangles = 0;
    int local_trunks = 0;  // usable (finite, de-duplicated) local trunks
    double rms_m = 0;
    std::vector<std::pair<int, int>> matches;  // (local row, map row) inlier pairs
    Eigen::Matrix3d transform() const;         // homogeneous 2D T_map_local
};

// 2D rigid transform minimizing sum |R p_i + t - q_i|^2 (closed form); returns (x, y, yaw).
// local and map pair up row by row (std::invalid_argument when their lengths differ).
Eigen::Vector3d fitRigid2D(const std::vector<Eigen::Vector2d> &local,
                           const std::vector<Eigen::Vector2d> &map);

class TreeMap {
  public:
    TreeMap() = default;
    // Triangulates xy (M,2), builds the star features and their index. dbh (M,) stem
    // diameters (m, NaN where unknown; empty: none) make DBH evidence possible.
    explicit TreeMap(const Eigen::Ref<const Points2> &xy, double duplicate_tolerance_m = 0.01,
                     const Eigen::VectorXd &dbh = {});

    // local_dbh (K,) the local trunks' diameters (m, NaN where unknown; empty: none).
    // observations (K,) in how many aggregated frames each trunk was detected (empty: unknown):
    // the single-triangle stage tries triangles of trunks seen in >= 2 frames first (transient
    // false detections are seen once); the acceptance test does not use them. Another length
    // than local_xy's is std::invalid_argument.
    GlobalLocalization localize(const Eigen::Ref<const Points2> &local_xy,
                                const GlobalLocalizerConfig &config = {},
                                const Eigen::VectorXd &local_dbh = {},
                                const Eigen::VectorXi &observations = {}) const;

    const Points2 &points() const { return xy_; }
    bool hasDbh() const { return !dbh_neighbours_.empty(); }
    const Triangulation &triangulation() const { return tri_; }
    const StarSet &stars() const { return stars_; }

  private:
    struct Query;       // the local trunks as the matchers use them (global_localizer.cpp)
    struct Hypotheses;  // the verified hypotheses of one query (global_localizer.cpp)
    struct Selection;   // the tested answer and runner-up among the hypotheses

    // Stage 1, stars (the paper's method, verified by edge lengths and the side test), then
    // when rejected stage 2, single triangles; each stage ends in decide().
    GlobalLocalization localizeDefault(const GlobalLocalization &base, const Query &q,
                                       const GlobalLocalizerConfig &cfg) const;
    // Stage 1's hypotheses into hyps, nearest stars first, until one explains `decisive`
    // trunks; returns the query stars tried.
    int starHypotheses(const Query &q, const GlobalLocalizerConfig &cfg, int decisive,
                       Hypotheses &hyps) const;
    // One local star (in one vertex rotation) against its nearest map stars.
    void matchStar(const Query &q, const Star &star, const GlobalLocalizerConfig &cfg,
                   Hypotheses &hyps) const;
    // Stage 2's hypotheses into hyps: triangles of each trunk with two of its nearest
    // neighbours, nearest first, bounded by decisive and max_fallback_matches.
    void triangleHypotheses(const Query &q, const GlobalLocalizerConfig &cfg, int decisive,
                            Hypotheses &hyps) const;
    void matchTriangle(const Query &q, const std::array<int, 3> &t,
                       const GlobalLocalizerConfig &cfg, Hypotheses &hyps) const;
    // Li et al. as written: interior local stars with no vertex on the local hull, matched to
    // map stars by feature distance; vertices in canonical order (Eq. 2); the rotation is the
    // candidate angle between corresponding centre edges minimizing the squared vertex
    // residuals (Eq. 3); every match votes in (beta, Dx, Dy) and the fullest bin wins (Eq. 4).
    // Then the same refinement and acceptance test as the default matcher.
    GlobalLocalization localizePaper(GlobalLocalization res, const Query &q,
                                     const GlobalLocalizerConfig &cfg) const;
    // Eq. 2-4: one hypothesis per (beta, Dx, Dy) bin, scored by its votes, in a deterministic
    // order; query_stars counts the stars that voted.
    std::vector<Hypothesis> paperHypotheses(const Query &q, const GlobalLocalizerConfig &cfg,
                                            int &query_stars) const;
    // searched: the hypotheses tested (the multiple-testing count of the acceptance test):
    // verified matches whose poses are distinct by hash (a repeat is not tested again).
    GlobalLocalization decide(const GlobalLocalization &base, std::vector<Hypothesis> &hyps,
                              int searched, const Query &q, const GlobalLocalizerConfig &cfg) const;
    // Sorts hyps by score and tests the best few: the most significant wins (paper: the
    // fullest), the runner-up is the most significant distinct one.
    Selection select(std::vector<Hypothesis> &hyps, int searched, const Query &q,
                     const GlobalLocalizerConfig &cfg) const;
    // Verified matches whose pose agrees with the answer (within the distinct thresholds).
    int agreeing(const std::vector<Eigen::Vector3d> &matches, const GlobalLocalization &res,
                 const GlobalLocalizerConfig &cfg) const;
    // The acceptance test's evidence for `pose` on the scoring trunks, fitted to `seeds` points,
    // the best of `searched`, its seed match's own evidence seed_evidence (nats).
    // scoring_dbh: the scoring trunks' diameters (empty: none).
    ChanceEvidence evidence(const Points2 &scoring, const Eigen::VectorXd &scoring_dbh,
                            const Eigen::Vector3d &pose, int seeds, int searched,
                            double seed_evidence, const GlobalLocalizerConfig &cfg) const;
    // ln LR of one pair's DBH agreement against map trunk j's neighbourhood (acceptance.hpp);
    // NaN when either side has no DBH.
    double dbhAgreement(int j, double local_dbh, const GlobalLocalizerConfig &cfg) const;
    void buildDbhNeighbourhoods(const Eigen::VectorXd &dbh);
    // Sum of the chance rates of local trunks mapped by pose (see acceptance.hpp).
    double expectedChance(const Points2 &local, const Eigen::Vector3d &pose, double gate) const;

    Points2 xy_;
    Triangulation tri_;
    StarSet stars_;
    KdTree index_;                              // embedded star features
    std::vector<std::array<int, 3>> triplets_;  // nearest-neighbour triangles (fallback)
    KdTree triangle_index_;                     // their side lengths, ccw from the shortest
    PointGrid grid_;
    DensityGrid density_;
    Eigen::VectorXd dbh_;  // per map row, NaN where unknown (empty: no DBH)
    // Per map row with a DBH: the sorted DBHs of its kDbhNeighbours nearest trunks with one.
    std::vector<std::vector<float>> dbh_neighbours_;
};

}  // namespace forestslam::localization
