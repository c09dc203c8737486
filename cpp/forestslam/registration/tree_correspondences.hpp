// Tree correspondences: mutually exclusive nearest neighbours of stem positions in the XY plane,
// gated, after moving the source stems by a predicted pose (constant-velocity model).
#pragma once

#include <utility>
#include <vector>

#include "forestslam/common/types.hpp"

namespace forestslam::registration {

// source, target: (K,3)/(M,3) stem positions (x, y, z), each in its own frame; only XY of the
// predicted source positions is compared. A pair (i, j) is kept when target j is the nearest
// target of source i, source i is the nearest source of target j (mutual), and their XY distance
// is at most gate_m. ratio < 1 additionally drops ambiguous pairs whose second-nearest target is
// within distance/ratio (1 disables). Non-finite rows never match. std::invalid_argument unless
// gate_m > 0 and 0 < ratio <= 1.
std::vector<std::pair<int, int>> matchTrees(const Eigen::Ref<const Points3> &source,
                                            const Eigen::Ref<const Points3> &target,
                                            const Pose3 &T_target_source_predicted, double gate_m,
                                            double ratio = 1.0);

}  // namespace forestslam::registration
