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
#pragma once

#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam {

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

// -log10 P(X >= k) for X ~ Poisson(mu); 0 when k <= 0.
double poissonTailLog10(double mu, int k);

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
    double significance = 0.0;  // -log10(hypotheses * P(chance inliers >= inliers - seeds))
};

// Evidence of `inliers` among `trials` local trunks whose chance rates sum to `expected`, the
// best of `hypotheses` searched, fitted to `seed_points`.
ChanceEvidence chanceEvidence(int inliers, int trials, double expected, int seed_points,
                              int hypotheses);

struct AcceptanceVerdict {
    bool accepted = false;
    std::string reason;  // empty when accepted
};

// Accept the best hypothesis when it is significant and no distinct runner-up comes close:
// runner_up_fraction (the runner-up's consensus over the best's, on the same trunks) below
// config.ambiguity_ratio.
AcceptanceVerdict judge(const ChanceEvidence &best, double runner_up_fraction,
                        const AcceptanceConfig &config);

}  // namespace forestslam
