// The median the core's robust statistics share (perception's stem tests and silhouettes).
#pragma once

#include <algorithm>
#include <cstddef>
#include <limits>
#include <vector>

namespace forestslam {

// Upper median of `v` (the element at size / 2 in sorted order, no averaging: it is one of the
// values); NaN when empty.
inline double median(std::vector<double> v) {
    if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
    const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
    std::nth_element(v.begin(), mid, v.end());
    return *mid;
}

}  // namespace forestslam
