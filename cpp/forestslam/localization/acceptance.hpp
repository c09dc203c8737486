// Calibrated acceptance of a pose hypothesis (global localization, loop closure,
// relocalization): how likely is it that this many local trunks land within the gate of a map
// trunk by chance, given the map's local trunk density?
//
// Under a wrong pose the local trunks fall on the map like random points: trunk i lands within
// the gate of some map trunk with probability p_i = 1 - exp(-lambda(q_i) pi gate^2), lambda the
// map density around its mapped position q_i. The inlier count beyond the points the hypothesis
// was fitted to (6 for a star, 3 for a triangle) is then a sum of Bernoulli(p_i), bounded by a
// Poisson(sum p_i) tail (larger variance: conservative). The best of H hypotheses is corrected
// for the search (Bonferroni): significance = -log10(H * P(X >= k)).
//
// How close the inliers land carries evidence too: under a wrong pose a chance inlier's
// U_i = P(D <= d_i) = 1 - exp(-lambda pi d_i^2) is uniform on [0, p_i], so -ln(U_i / p_i) is
// Exp(1). The truncated product of the inliers' U_i (Zaykin et al. 2002) tests count and
// closeness together: S = sum over inliers of (c + -ln(U_i / p_i)), c = -ln(mean p_i), is under
// the null a Poisson(mu) number of terms c + Exp(1). A true pose puts its inliers within the
// positioning noise (centimetres) of their trunks, far inside the gate: in a sparse map 5
// trunks fitted within 7 cm are as significant as 12 counted in the 0.5 m gate.
//
// The seed match itself is evidence too: a hypothesis is verified when its seed shape (3 side
// lengths of a triangle, 9 edge lengths of a star) agrees with a map shape within the edge
// tolerance. A chance match agrees anywhere in that tolerance (the map's shapes are smooth at
// that scale: locally uniform), a true one within the positioning noise. With d the norm of the
// m edge differences and R the radius of the region searched (the tolerance, or the k-th
// neighbour's distance when the index returned all k), P(norm <= d) <= (d / R)^m under the null:
// the ball of radius R lies inside the region searched (conservative). -ln of it is one more
// Exp(1) term of the sum above (as in Fisher's method: the search pays for both).
//
// Optional: stem diameters, when both the map and the query have them. A chance inlier's map
// trunk j is any trunk of its neighbourhood N (DBH does not depend on position at that scale),
// so the query DBH d is weighed by the likelihood ratio
//   LR = (1 - eps) phi(d - d_j) / f(d) + eps,   f(d) = mean over k in N of phi(d - d_k),
// phi the N(0, sigma) density of a DBH difference, eps the fraction of gross DBH errors. Its
// mean over j drawn from N is exactly 1 whatever d is, so under a chance pose E[prod LR] = 1 and
// P(p / prod LR <= a) <= a for the geometric p-value p (Markov: the ratio is an e-value): the
// significance gains log10 of the product and stays a probability of chance. A DBH that agrees
// adds up to ln(1 / (f sqrt(2 pi) sigma)) per pair (about 1 nat in a stand whose DBH spread is
// 3 sigma); one that is grossly wrong costs at most ln(1 / eps). A query whose DBHs are useless
// as a whole (biased, another mapper's definition of the diameter) would lose that on every
// pair, so the evidence is the mixture w prod LR + (1 - w) (an average of e-values is one); with
// w = 1/4 useless DBHs cost at most ln(4/3) nats (0.12 decades), informative ones gain the
// product's ln less ln 4 (a half-half mixture let absent views near the threshold through:
// 2 of 1,000 views of a uniform stand in the longleaf map, 0 with positions only).
#pragma once

#include <cstdint>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam::localization {

// Map trunk density (trunks per m^2) averaged over a square window around any position.
class DensityGrid {
  public:
    DensityGrid() = default;
    // xy (M,2); the window is (2 * half_window + 1) cells of cell_m on a side.
    explicit DensityGrid(const Eigen::Ref<const Points2> &xy, double cell_m = 4.0,
                         int half_window = 2);
    double at(double x, double y) const;

  private:
    static uint64_t key(int64_t ix, int64_t iy) {
        return (static_cast<uint64_t>(static_cast<uint32_t>(ix)) << 32) | static_cast<uint32_t>(iy);
    }
    double cell_ = 4.0;
    double window_area_ = 400.0;
    std::unordered_map<uint64_t, int> counts_;  // trunks in the window around each cell
};

// ln P(Gamma(n, 1) >= x) for integer n >= 1 (0 when x <= 0).
double gammaTailLn(int n, double x);

// ln LR of a query DBH against map trunk DBH map_dbh whose neighbourhood's DBHs (map_dbh among
// them) are `neighbourhood` (see above); 0 when the neighbourhood is empty.
double dbhLogRatio(double local_dbh, double map_dbh, const std::vector<float> &neighbourhood,
                   double sigma_m, double outlier_fraction);

// The DBH evidence of pairs whose ln LR sum to sum_ln_ratio: ln(w prod LR + 1 - w), nats (see
// above); in [ln(1 - w), sum_ln_ratio].
double dbhEvidence(double sum_ln_ratio, double weight = 0.25);

// -log10 P(X >= k) for X ~ Poisson(mu); 0 when k <= 0.
double poissonTailLog10(double mu, int k);

// -log10 P(S >= k c + w) for S = sum of N ~ Poisson(mu) terms c + Exp(1) (truncated product of
// k chance inliers whose closeness sum is w, see above), plus extra_terms independent Exp(1)
// terms (the seed match's evidence, counted in w); 0 when k + extra_terms <= 0.
double truncatedProductTailLog10(double mu, double c, int k, double w, int extra_terms = 0);

// -ln(U / p) of one inlier at distance d_m from its map trunk (U = P(D <= d), p = P(D <= gate)
// at density lambda); distances below floor_m (the positioning noise) count as floor_m.
double closeness(double density, double d_m, double gate_m, double floor_m);

// -ln P(norm of m chance edge differences <= deviation_m) = m ln(R / d), d at least
// floor_m * sqrt(m) (the positioning noise), 0 when d >= R (see above).
double seedEvidence(double deviation_m, double radius_m, int m, double floor_m);

// -ln P(norm of m chance edge differences <= deviation_m) when the differences searched were
// every one within half_width_m on each axis (a cube; the search found them all): the ball of
// radius d over the cube, -ln(V_m(d) / (2 h)^m), d at least floor_m * sqrt(m); 0 when that is
// negative. Sharper than seedEvidence(deviation, h, m, floor) by m ln 2 - ln V_m(1) (0.65 nats
// for a triangle's 3 sides) and as exact: the density of map shapes is flat in the cube too.
double seedEvidenceCube(double deviation_m, double half_width_m, int m, double floor_m);

// Each pair's residual under the rigid fit to all the other pairs (leave-one-out, closed form;
// local and map rows paired by `pairs`), as the radius of the circle with the area of the
// error ellipse through it; empty when fewer than 4 pairs.
//
// With isotropic position noise, the fit to m points predicts a trunk at lever arm r from
// their centroid with a covariance proportional to (1 + 1/m) I + r_perp r_perp^T / S (S: the m
// points' spread about their centroid): a far trunk of a small seed triangle is uncertain along
// its arc, not towards the centroid. The ellipse {x : x^T Sigma^-1 x <= e^T Sigma^-1 e} has area
// pi e^T Sigma^-1 e sqrt(det Sigma) for any scale of Sigma (no noise level is needed). Under a
// chance pose a map trunk falls in it as likely as in a circle of the same area (the density
// does not care about the shape, and Sigma depends only on the local trunks), so the radius
// takes the plain residual's place in closeness(): a conservative p-value still (the ellipse
// may reach outside the gate), a sharper one for a true pose. Sigma isotropic (a trunk at the
// others' centroid): the plain residual.
std::vector<double> leaveOneOutRadii(const Points2 &local, const Points2 &map,
                                     const std::vector<std::pair<int, int>> &pairs);

// Chance probability that one trunk lands within gate_m of a map trunk at density lambda.
double chanceRate(double density, double gate_m);

struct AcceptanceConfig {
    double min_significance = 2.3;  // accept when the corrected chance probability < 0.005
    double ambiguity_ratio = 0.8;   // reject when a distinct runner-up scores this much of the best
    int min_inliers = 6;            // absolute floor
};

// One hypothesis as the test sees it.
struct ChanceEvidence {
    int inliers = 0;            // local trunks within the gate under the pose
    int seed_points = 0;        // points the pose was fitted to (inliers by construction)
    double expected = 0.0;      // sum of p_i over the local trunks tested
    int trials = 0;             // local trunks tested
    double closeness = -1.0;    // sum of -ln(U_i / p_i) over the non-seed inliers; < 0: unknown
    double seed = 0.0;          // the seed match's evidence (seedEvidence), nats
    double dbh = 0.0;           // the inliers' DBH agreement, sum of ln LR (nats); 0: none
    int dbh_pairs = 0;          // inlier pairs with a DBH on both sides
    double significance = 0.0;  // -log10(hypotheses * P(chance inliers >= inliers - seeds))
};

// Evidence of `inliers` among `trials` local trunks whose chance rates sum to `expected`, the
// best of `hypotheses` searched, fitted to `seed_points`. With `closeness` >= 0 (the sum of
// closeness() over the inliers that are not seeds: the seed_points closest inliers left out)
// the truncated-product tail, otherwise the count's Poisson tail; with seed > 0 (nats) the seed
// match's evidence joins it (one more Exp(1) term, Fisher's combination for the Poisson tail).
// dbh: the inliers' summed ln LR of their DBHs (nats, any sign), which divides the p-value.
ChanceEvidence chanceEvidence(int inliers, int trials, double expected, int seed_points,
                              int hypotheses, double closeness = -1.0, double seed = 0.0,
                              double dbh = 0.0);

struct AcceptanceVerdict {
    bool accepted = false;
    std::string reason;  // empty when accepted
};

// Accept the best hypothesis when it is significant and no distinct runner-up comes close:
// runner_up_fraction (the runner-up's consensus over the best's, on the same trunks) below
// config.ambiguity_ratio.
AcceptanceVerdict judge(const ChanceEvidence &best, double runner_up_fraction,
                        const AcceptanceConfig &config);

}  // namespace forestslam::localization
