#include "forestslam/registration/stem_centre_lm.hpp"

#include <ceres/ceres.h>
#include <pcl/kdtree/kdtree_flann.h>

#include <Eigen/Dense>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

#include "forestslam/common/pcl_adapter.hpp"

namespace forestslam::registration {

namespace {
constexpr double kCell = 0.2;  // x-y column of the target for the virtual-feature search
std::int64_t cellIndex(double v) { return static_cast<std::int64_t>(std::floor(v / kCell)); }
std::int64_t cellKey(std::int64_t ix, std::int64_t iy) {
    return ((ix & 0x7FFFFFFF) << 32) | (iy & 0x7FFFFFFF);
}
// The target points of the x-y columns, each column's sorted by height (a height window is one
// binary search), stored one column after another in two flat arrays: one allocation instead of
// one per column.
struct Column {
    int begin = 0, end = 0;  // its range in Columns::z / Columns::index
};
// Column of a key by open addressing (keys are non-negative, -1 marks a free slot): a map
// target holds ~10^5 columns, and every candidate search looks up a dozen of them (the
// node-based std::unordered_map's lookups and its build were a visible share of the LM).
class ColumnTable {
  public:
    void reserve(std::size_t n) {
        std::size_t size = 16;
        while (size < 2 * n) size *= 2;
        keys_.assign(size, -1);
        columns_.assign(size, Column{});
        mask_ = size - 1;
    }
    // The column of key, inserted as `fresh` when absent (added says which).
    Column &insert(std::int64_t key, const Column &fresh, bool &added) {
        std::size_t i = slot(key);
        added = keys_[i] != key;
        if (added) {
            keys_[i] = key;
            columns_[i] = fresh;
        }
        return columns_[i];
    }
    const Column *find(std::int64_t key) const {
        if (keys_.empty()) return nullptr;
        const std::size_t i = slot(key);
        return keys_[i] == key ? &columns_[i] : nullptr;
    }

  private:
    std::size_t slot(std::int64_t key) const {  // the key's slot, or the free one it would take
        auto h = static_cast<std::uint64_t>(key) * 0x9E3779B97F4A7C15ULL;
        std::size_t i = static_cast<std::size_t>(h ^ (h >> 29)) & mask_;
        while (keys_[i] != -1 && keys_[i] != key) i = (i + 1) & mask_;
        return i;
    }
    std::vector<std::int64_t> keys_;
    std::vector<Column> columns_;
    std::size_t mask_ = 0;
};
struct Columns {
    ColumnTable at;
    std::vector<double> z;
    std::vector<int> index;
};

// Counting sort of the points by column (ascending point index within a column), then each
// column sorted by height with the same comparisons as a per-column std::sort of its indices.
Columns buildColumns(const Points3 &pts) {
    Columns c;
    const auto n = static_cast<std::size_t>(pts.rows());
    std::vector<int> column_of(n);
    std::vector<int> counts;
    std::vector<std::int64_t> keys;
    c.at.reserve(n);  // at most one column per point
    for (std::size_t i = 0; i < n; ++i) {
        const auto key = cellKey(cellIndex(pts(static_cast<Eigen::Index>(i), 0)),
                                 cellIndex(pts(static_cast<Eigen::Index>(i), 1)));
        bool added = false;
        const Column &col = c.at.insert(key, Column{static_cast<int>(keys.size()), 0}, added);
        if (added) {
            keys.push_back(key);
            counts.push_back(0);
        }
        column_of[i] = col.begin;  // the column's ordinal until the ranges are set
        ++counts[static_cast<std::size_t>(col.begin)];
    }
    std::vector<int> start(keys.size() + 1, 0);
    for (std::size_t k = 0; k < keys.size(); ++k) start[k + 1] = start[k] + counts[k];
    bool added = false;
    for (std::size_t k = 0; k < keys.size(); ++k)
        c.at.insert(keys[k], Column{}, added) = Column{start[k], start[k + 1]};
    struct Entry {
        double z;
        int index;
    };
    std::vector<Entry> entries(n);
    std::vector<int> fill(start.begin(), start.end() - 1);
    for (std::size_t i = 0; i < n; ++i)
        entries[static_cast<std::size_t>(fill[static_cast<std::size_t>(column_of[i])]++)] = {
            pts(static_cast<Eigen::Index>(i), 2), static_cast<int>(i)};
    for (std::size_t k = 0; k < keys.size(); ++k)
        std::sort(entries.begin() + start[k], entries.begin() + start[k + 1],
                  [](const Entry &a, const Entry &b) { return a.z < b.z; });
    c.z.resize(n);
    c.index.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
        c.z[i] = entries[i].z;
        c.index[i] = entries[i].index;
    }
    return c;
}
}  // namespace

// The target's points, their x-y columns (the stem-centre pairs' disc and height window; the
// real features' cached neighbourhoods) and PCL's k-d tree (FLANN, single precision), built on
// first use: the real features' nearest points are FLANN's answers, which the neighbourhoods
// reproduce exactly wherever they can (RealCandidates), so most targets never build the tree
// (its build was most of a target's cost, and the LM's map target is rebuilt often).
struct StemCentreTarget::Impl {
    Points3 points;
    Columns columns;
    std::uint64_t id = 0;  // unique per target built (a cache never mistakes a new one)

    // The k nearest points of q as FLANN answers them: rows and single-precision squared
    // distances, nearest first, ties in the tree's order.
    int nearestK(const Eigen::Vector3d &q, int k, std::vector<int> &rows,
                 std::vector<float> &d2) const {
        std::call_once(tree_once_, [this] {
            cloud_ = detail::toPcl(points);
            if (!cloud_->empty()) tree_.setInputCloud(cloud_);
        });
        if (cloud_->empty()) {
            rows.clear();
            d2.clear();
            return 0;
        }
        const pcl::PointXYZ query(static_cast<float>(q.x()), static_cast<float>(q.y()),
                                  static_cast<float>(q.z()));
        return tree_.nearestKSearch(query, k, rows, d2);
    }

    // Appends (squared distance, row) of every point within radius of q: per column that the
    // ball reaches, the height window the ball leaves at the column's nearest x-y point.
    void withinRadius(const Eigen::Vector3d &q, double radius,
                      std::vector<std::pair<double, int>> &out) const {
        const double r2 = radius * radius;
        const auto gap = [](double v, std::int64_t cell) {  // distance from v to the cell's span
            const double lo = static_cast<double>(cell) * kCell, hi = lo + kCell;
            return v < lo ? lo - v : (v > hi ? v - hi : 0.0);
        };
        for (auto ix = cellIndex(q.x() - radius); ix <= cellIndex(q.x() + radius); ++ix) {
            const double gx = gap(q.x(), ix);
            for (auto iy = cellIndex(q.y() - radius); iy <= cellIndex(q.y() + radius); ++iy) {
                const double gy = gap(q.y(), iy);
                const double h2 = r2 - gx * gx - gy * gy;
                if (h2 < -1e-9) continue;
                const Column *col = columns.at.find(cellKey(ix, iy));
                if (col == nullptr) continue;
                // Slightly wider than the exact window: the distance test below decides.
                const double h = std::sqrt(std::max(h2, 0.0)) + 1e-6;
                const auto z0 = columns.z.begin() + col->begin;
                const auto z1 = columns.z.begin() + col->end;
                const auto hi = std::upper_bound(z0, z1, q.z() + h);
                for (auto k = std::lower_bound(z0, hi, q.z() - h); k < hi; ++k) {
                    const int j = columns.index[static_cast<std::size_t>(k - columns.z.begin())];
                    const double dx = points(j, 0) - q.x(), dy = points(j, 1) - q.y(),
                                 dz = points(j, 2) - q.z();
                    const double d2 = dx * dx + dy * dy + dz * dz;
                    if (d2 <= r2) out.emplace_back(d2, j);
                }
            }
        }
    }

  private:
    mutable std::once_flag tree_once_;
    mutable pcl::PointCloud<pcl::PointXYZ>::Ptr cloud_;
    mutable pcl::KdTreeFLANN<pcl::PointXYZ> tree_;
};

StemCentreTarget::StemCentreTarget(const Eigen::Ref<const Points3> &points)
    : impl_(std::make_unique<Impl>()) {
    static std::atomic<std::uint64_t> next_id{1};
    impl_->points = finiteRows(points);
    impl_->columns = buildColumns(impl_->points);
    impl_->id = next_id++;
}

StemCentreTarget::~StemCentreTarget() = default;
Eigen::Index StemCentreTarget::size() const { return impl_->points.rows(); }
const Points3 &StemCentreTarget::points() const { return impl_->points; }

namespace {

struct VirtualPair {
    Eigen::Vector3d centre, target;
    double radius;
    double weight;  // virtual_weight shared by the pairs of one centre
    Eigen::Index index;
};
struct PlanePair {
    Eigen::Vector3d source, origin, normal;
    Eigen::Index index;
};

// The Cauchy-robust residual of raw residual r with scale c, as one least-squares term:
// f = sign(r) sqrt(rho(r)), rho(r) = c^2 log(1 + r^2 / c^2), and df/dr = r / ((1 + r^2/c^2) f)
// (-> 1 at r = 0).
void cauchyResidual(double r, double c, double &f, double &df) {
    const double u = r / c;
    if (std::abs(u) < 1e-6) {
        f = r;
        df = 1.0;
        return;
    }
    f = std::copysign(c * std::sqrt(std::log1p(u * u)), r);
    df = r / ((1.0 + u * u) * f);
}

// All pairs of one correspondence round in one residual block with analytic Jacobians. The
// parameters are a left perturbation [dt (3), dw (3)] of the round's starting pose T0:
// q = exp(dw) (R0 s + t0) + dt. Pair i has the raw residual r_i = d - r (virtual: d the
// horizontal distance to the paired target point) or the point-to-plane distance (real) and
// contributes w_i * rho(r_i) with rho the Cauchy loss of scale c: the block returns
// f_i = sqrt(w_i) sign(r_i) sqrt(rho(r_i)), rho(r) = c^2 log(1 + r^2 / c^2), so that the sum of
// squares is exactly the robust cost (one block instead of one per pair: the per-block
// overhead dominated). Jacobian of q w.r.t. dw: -[q]x (exact at dw = 0, first order within
// the round's small step).
class PairsCost : public ceres::CostFunction {
  public:
    PairsCost(const std::vector<VirtualPair> &v, const std::vector<PlanePair> &p,
              const Eigen::Matrix4d &T0, double scale)
        : v_(v), p_(p), c_(scale) {
        R0_ = T0.block<3, 3>(0, 0);
        t0_ = T0.block<3, 1>(0, 3);
        set_num_residuals(static_cast<int>(v.size() + p.size()));
        mutable_parameter_block_sizes()->push_back(6);
    }

    bool Evaluate(double const *const *parameters, double *residuals,
                  double **jacobians) const override {
        const double *d = parameters[0];
        const Eigen::Vector3d dt(d[0], d[1], d[2]), dw(d[3], d[4], d[5]);
        const double angle = dw.norm();
        const Eigen::Matrix3d dR = angle > 0
                                       ? Eigen::AngleAxisd(angle, dw / angle).toRotationMatrix()
                                       : Eigen::Matrix3d::Identity();
        const Eigen::Matrix3d R = dR * R0_;
        const Eigen::Vector3d t = dR * t0_ + dt;
        double *J = (jacobians != nullptr) ? jacobians[0] : nullptr;
        std::size_t i = 0;
        for (const auto &v : v_) {
            const Eigen::Vector3d q = R * v.centre + t;
            const double dx = q.x() - v.target.x(), dy = q.y() - v.target.y();
            const double dn = std::sqrt(dx * dx + dy * dy + 1e-12);
            double f, df;
            robust(dn - v.radius, f, df);
            const double w = std::sqrt(v.weight);
            residuals[i] = w * f;
            if (J != nullptr) {
                const Eigen::Vector3d u(dx / dn, dy / dn, 0.0);
                writeRow(J + 6 * i, u, q, w * df);
            }
            ++i;
        }
        for (const auto &p : p_) {
            const Eigen::Vector3d q = R * p.source + t;
            double f, df;
            robust(p.normal.dot(q - p.origin), f, df);
            residuals[i] = f;
            if (J != nullptr) writeRow(J + 6 * i, p.normal, q, df);
            ++i;
        }
        return true;
    }

  private:
    void robust(double r, double &f, double &df) const { cauchyResidual(r, c_, f, df); }

    // d r / d [dt, dw] = [u, q x u] (u the residual direction), scaled by w.
    static void writeRow(double *row, const Eigen::Vector3d &u, const Eigen::Vector3d &q,
                         double w) {
        const Eigen::Vector3d qu = q.cross(u);
        for (int k = 0; k < 3; ++k) {
            row[k] = w * u[k];
            row[3 + k] = w * qu[k];
        }
    }

    const std::vector<VirtualPair> &v_;
    const std::vector<PlanePair> &p_;
    double c_;
    Eigen::Matrix3d R0_;
    Eigen::Vector3d t0_;
};

// In-sweep motion: the pairs of one round with the features at their current positions q
// (pose and in-sweep motion so far) and times tau; the parameters are a perturbation per
// polynomial order k = 0..K, [dt_k (3), dw_k (3)], the feature at tau moving to
// exp(sum_k tau^k dw_k) (q - o) + o + sum_k tau^k dt_k (o the sensor position). Same robust
// residuals as PairsCost; d/d[dt_k, dw_k] = tau^k [u, (q - o) x u].
class SweepPairsCost : public ceres::CostFunction {
  public:
    SweepPairsCost(const std::vector<VirtualPair> &v, const std::vector<PlanePair> &p,
                   const Points3 &qc, const Points3 &qr, const Eigen::VectorXd &tc,
                   const Eigen::VectorXd &tr, const Eigen::Vector3d &origin, int order,
                   double scale)
        : v_(v), p_(p), qc_(qc), qr_(qr), tc_(tc), tr_(tr), o_(origin), K_(order), c_(scale) {
        set_num_residuals(static_cast<int>(v.size() + p.size()));
        mutable_parameter_block_sizes()->push_back(6 * (order + 1));
    }

    bool Evaluate(double const *const *parameters, double *residuals,
                  double **jacobians) const override {
        const double *d = parameters[0];
        const int np = 6 * (K_ + 1);
        double *J = (jacobians != nullptr) ? jacobians[0] : nullptr;
        std::size_t i = 0;
        auto move = [&](const Eigen::Vector3d &q, double tau, Eigen::Vector3d &moved) {
            Eigen::Vector3d dt = Eigen::Vector3d::Zero(), dw = Eigen::Vector3d::Zero();
            double pw = 1.0;
            for (int k = 0; k <= K_; ++k) {
                dt += pw * Eigen::Vector3d(d[6 * k], d[6 * k + 1], d[6 * k + 2]);
                dw += pw * Eigen::Vector3d(d[6 * k + 3], d[6 * k + 4], d[6 * k + 5]);
                pw *= tau;
            }
            const double angle = dw.norm();
            const Eigen::Matrix3d dR = angle > 0
                                           ? Eigen::AngleAxisd(angle, dw / angle).toRotationMatrix()
                                           : Eigen::Matrix3d::Identity();
            moved = dR * (q - o_) + o_ + dt;
        };
        auto writeRow = [&](double *row, const Eigen::Vector3d &u, const Eigen::Vector3d &q,
                            double tau, double w) {
            const Eigen::Vector3d qu = (q - o_).cross(u);
            double pw = 1.0;
            for (int k = 0; k <= K_; ++k) {
                for (int c = 0; c < 3; ++c) {
                    row[6 * k + c] = w * pw * u[c];
                    row[6 * k + 3 + c] = w * pw * qu[c];
                }
                pw *= tau;
            }
        };
        Eigen::Vector3d q;
        for (const auto &v : v_) {
            const double tau = tc_[v.index];
            move(qc_.row(v.index).transpose(), tau, q);
            const double dx = q.x() - v.target.x(), dy = q.y() - v.target.y();
            const double dn = std::sqrt(dx * dx + dy * dy + 1e-12);
            double f, df;
            robust(dn - v.radius, f, df);
            const double w = std::sqrt(v.weight);
            residuals[i] = w * f;
            if (J != nullptr)
                writeRow(J + np * i, Eigen::Vector3d(dx / dn, dy / dn, 0.0), q, tau, w * df);
            ++i;
        }
        for (const auto &p : p_) {
            const double tau = tr_[p.index];
            move(qr_.row(p.index).transpose(), tau, q);
            double f, df;
            robust(p.normal.dot(q - p.origin), f, df);
            residuals[i] = f;
            if (J != nullptr) writeRow(J + np * i, p.normal, q, tau, df);
            ++i;
        }
        return true;
    }

  private:
    void robust(double r, double &f, double &df) const { cauchyResidual(r, c_, f, df); }

    const std::vector<VirtualPair> &v_;
    const std::vector<PlanePair> &p_;
    const Points3 &qc_, &qr_;
    const Eigen::VectorXd &tc_, &tr_;
    Eigen::Vector3d o_;
    int K_;
    double c_;
};

// Zero prior on the in-sweep coefficients (orders 1..K): residual s (c_k + d_k) tau0^k / sigma,
// s the feature residuals' scale (metres), so that the prior weighs like one feature whose
// residual is s when the coefficient's effect at tau0 is sigma.
class SweepPriorCost : public ceres::CostFunction {
  public:
    SweepPriorCost(const Eigen::MatrixXd &current, double tau0, double sigma_m, double sigma_rad,
                   double scale_m)
        : c_(current), tau0_(tau0), sm_(sigma_m / scale_m), sr_(sigma_rad / scale_m) {
        const auto K = static_cast<int>(current.rows());
        set_num_residuals(6 * K);
        mutable_parameter_block_sizes()->push_back(6 * (K + 1));
    }

    bool Evaluate(double const *const *parameters, double *residuals,
                  double **jacobians) const override {
        const double *d = parameters[0];
        const auto K = static_cast<int>(c_.rows());
        const int np = 6 * (K + 1);
        double *J = (jacobians != nullptr) ? jacobians[0] : nullptr;
        if (J != nullptr) std::fill(J, J + static_cast<std::size_t>(6 * K * np), 0.0);
        double pw = tau0_;
        for (int k = 1; k <= K; ++k) {
            for (int c = 0; c < 6; ++c) {
                const double w = pw / (c < 3 ? sm_ : sr_);
                const int r = 6 * (k - 1) + c;
                residuals[r] = w * (c_(k - 1, c) + d[6 * k + c]);
                if (J != nullptr) J[r * np + 6 * k + c] = w;
            }
            pw *= tau0_;
        }
        return true;
    }

  private:
    const Eigen::MatrixXd &c_;
    double tau0_, sm_, sr_;
};

// Target points that can pair with each virtual feature, gathered with a slack around where
// the centre was: reused while the moved centre stays within the slack (exact, as a pair needs
// |d - r| < gate <= virtual_max_gate_m and |dz| <= virtual_window_m), so the hash cells are
// scanned about once per registration instead of once per round.
struct VirtualCandidates {
    static constexpr double kSlack = 0.3;
    struct Member {
        double x, y, z;  // a copy of the target point: the per-round scan reads memory in order
        int index;
    };
    std::vector<Eigen::Vector3d> at;           // transformed centre when gathered
    std::vector<std::vector<Member>> members;  // target points, by height
    std::vector<double> gate_of;               // the gate they were gathered for
    std::vector<char> valid;

    // The widest gate of a registration (its first round's), not the cap: a call that starts
    // at the fine gates scans a quarter of the cells.
    static double gatherGate(const StemCentreLmConfig &cfg) {
        return std::min(cfg.virtual_max_gate_m,
                        cfg.virtual_gate_m * std::max(1.0, cfg.coarse_gate_factor));
    }

    void gather(const StemCentreTarget::Impl &target, std::size_t i, const Eigen::Vector3d &q,
                double radius, const StemCentreLmConfig &cfg) {
        if (at.size() <= i) {
            at.resize(i + 1);
            members.resize(i + 1);
            gate_of.resize(i + 1, 0.0);
            valid.resize(i + 1, 0);
        }
        auto &out = members[i];
        out.clear();
        const double gate = gatherGate(cfg);
        gate_of[i] = gate;
        const double reach = radius + gate + kSlack;
        const double window = cfg.virtual_window_m + kSlack;
        const double reach2 = reach * reach;
        for (auto ix = cellIndex(q.x() - reach); ix <= cellIndex(q.x() + reach); ++ix) {
            for (auto iy = cellIndex(q.y() - reach); iy <= cellIndex(q.y() + reach); ++iy) {
                const Column *col = target.columns.at.find(cellKey(ix, iy));
                if (col == nullptr) continue;
                const auto z0 = target.columns.z.begin() + col->begin;
                const auto z1 = target.columns.z.begin() + col->end;
                const auto lo = std::lower_bound(z0, z1, q.z() - window);
                const auto hi = std::upper_bound(lo, z1, q.z() + window);
                for (auto k = lo; k < hi; ++k) {
                    const int j =
                        target.columns
                            .index[static_cast<std::size_t>(k - target.columns.z.begin())];
                    const double dx = target.points(j, 0) - q.x(), dy = target.points(j, 1) - q.y();
                    if (dx * dx + dy * dy <= reach2)
                        out.push_back(
                            {target.points(j, 0), target.points(j, 1), target.points(j, 2), j});
                }
            }
        }
        // By height: a round reads only its centre's height window (a third of them).
        std::sort(out.begin(), out.end(), [](const Member &a, const Member &b) {
            return a.z < b.z || (a.z == b.z && a.index < b.index);
        });
        at[i] = q;
        valid[i] = 1;
    }

    // Members gathered for a wider gate (an earlier registration of the same features) serve
    // a narrower one once cut to its reach around the same place: exactly the members a
    // gather there would give, in the same order (the extra ones lie beyond every pair).
    const std::vector<Member> &near(const StemCentreTarget::Impl &target, std::size_t i,
                                    const Eigen::Vector3d &q, double radius,
                                    const StemCentreLmConfig &cfg) {
        const double gate = gatherGate(cfg);
        if (i >= valid.size() || !valid[i] || std::abs(q.z() - at[i].z()) > kSlack ||
            std::hypot(q.x() - at[i].x(), q.y() - at[i].y()) > kSlack || gate > gate_of[i]) {
            gather(target, i, q, radius, cfg);
        } else if (gate < gate_of[i]) {
            const double reach = radius + gate + kSlack, reach2 = reach * reach;
            auto &ms = members[i];
            ms.erase(std::remove_if(ms.begin(), ms.end(),
                                    [&](const Member &m) {
                                        const double dx = m.x - at[i].x(), dy = m.y - at[i].y();
                                        return !(dx * dx + dy * dy <= reach2);
                                    }),
                     ms.end());
            gate_of[i] = gate;
        }
        return members[i];
    }
};

// The kNearest nearest target points of each real feature exactly as the k-d tree (FLANN, single
// precision) finds them, mostly without it: from a cached neighbourhood, the points within
// `complete` of where the feature was when gathered (all within kReach, or the nearest
// kMaxMembers when more lie there, `complete` then the farthest one's distance). The k nearest
// of the moved feature q lie among them while it is within delta of there with
// d_k + 2 delta + 2 eps < complete (d_k the k-th nearest distance when gathered, eps the
// difference of single- and double-precision distances): they lie within
// d_k(q) + delta + 2 eps <= d_k + 2 delta + 2 eps of the old position. Their distances are
// computed as FLANN computes them (floats, (q - p) squared and summed over x, y, z), so without
// a tie they give its answer and order; a tie in the first k + 1 that reaches the positions a
// plane uses (findPlanePairs) and a neighbourhood too sparse for a ball of kMaxSparseReach to
// hold the k + 1 nearest ask the tree. A feature with no point
// within the gate (plus a margin) has no pair either way. A round then scans a few dozen points
// instead of descending the tree (a quarter of the LM's time), and the tree is built only when
// asked.
struct RealCandidates {
    static constexpr int kNearest = 10;  // the kPlaneCandidates
    static constexpr int kMaxMembers = 48;
    static constexpr double kReach = 0.3;  // gathered within this radius
    static constexpr double kMaxSparseReach = 4.8;
    enum class Mode : char { kMembers, kTree, kNoPair };
    static constexpr std::size_t kNoTie = std::numeric_limits<std::size_t>::max();
    struct Member {
        float x, y, z;
        int index;
    };
    std::vector<Eigen::Vector3d> at;
    std::vector<double> room;  // complete - d_k - 2 eps: reused while 2 delta < room
    std::vector<Mode> mode;
    std::vector<std::vector<Member>> members;
    std::vector<char> valid;
    std::vector<std::pair<double, int>> scratch;
    std::vector<std::pair<float, int>> sorted;

    static double singlePrecisionSlack(const Eigen::Vector3d &q, double reach) {
        return 1e-6 * (q.cwiseAbs().maxCoeff() + reach + 1.0);
    }

    void gather(const StemCentreTarget::Impl &target, std::size_t i, const Eigen::Vector3d &q,
                double gate) {
        auto &out = members[i];
        out.clear();
        at[i] = q;
        valid[i] = 1;
        room[i] = -1.0;  // asked again next round unless set below
        scratch.clear();
        target.withinRadius(q, kReach, scratch);
        if (scratch.size() < static_cast<std::size_t>(kNearest)) {
            sparse(target, i, q, gate);
            return;
        }
        double complete = kReach;
        if (scratch.size() > static_cast<std::size_t>(kMaxMembers)) {
            // The kMaxMembers nearest: every point nearer than the farthest kept one.
            std::nth_element(scratch.begin(), scratch.begin() + (kMaxMembers - 1), scratch.end());
            scratch.resize(kMaxMembers);
            complete = std::sqrt(scratch.back().first);
        }
        for (const auto &[dd, row] : scratch) out.push_back(member(target, row));
        std::nth_element(scratch.begin(), scratch.begin() + (kNearest - 1), scratch.end());
        const double dk = std::sqrt(scratch[kNearest - 1].first);
        mode[i] = Mode::kMembers;
        room[i] = complete - dk - 2.0 * singlePrecisionSlack(q, kReach);
    }

    // Fewer than k points within kReach: a ball grown (doubling, up to kMaxSparseReach) until
    // it surely holds the k + 1 nearest in single precision, all its points the members
    // (reused like gather's while 2 delta < radius - d_k - 2 eps); none within the gate (plus
    // a margin): no pair; else the tree.
    void sparse(const StemCentreTarget::Impl &target, std::size_t i, const Eigen::Vector3d &q,
                double gate) {
        const double eps = singlePrecisionSlack(q, kMaxSparseReach);
        const auto want = static_cast<std::size_t>(kNearest + 1);
        mode[i] = Mode::kTree;
        for (double radius = 2.0 * kReach; radius <= kMaxSparseReach; radius *= 2.0) {
            scratch.clear();
            target.withinRadius(q, radius, scratch);
            if (scratch.empty() && radius >= gate + 1e-4) {
                mode[i] = Mode::kNoPair;
                return;
            }
            if (scratch.size() < want) continue;
            std::nth_element(scratch.begin(), scratch.begin() + (want - 1), scratch.end());
            if (std::sqrt(scratch[want - 1].first) + 2.0 * eps > radius) continue;
            for (const auto &[dd, row] : scratch) members[i].push_back(member(target, row));
            mode[i] = Mode::kMembers;
            // Reused as a gathered neighbourhood is (the ball is complete to its radius): 40 %
            // of the gathers were these, asked again every round.
            const auto kth = std::max_element(scratch.begin(), scratch.begin() + (want - 1));
            room[i] = radius - std::sqrt(kth->first) - 2.0 * eps;
            return;
        }
    }

    static Member member(const StemCentreTarget::Impl &target, int row) {
        return {static_cast<float>(target.points(row, 0)),
                static_cast<float>(target.points(row, 1)),
                static_cast<float>(target.points(row, 2)), row};
    }

    // The (up to) kNearest nearest target points of q as FLANN's nearestKSearch answers them
    // (rows, single-precision squared distances, nearest first); how many. From position `tie`
    // on FLANN's order may differ (see fromMembers): the caller asks the tree when it looks there.
    int nearest(const StemCentreTarget::Impl &target, std::size_t i, const Eigen::Vector3d &q,
                double gate, std::vector<int> &rows, std::vector<float> &d2, std::size_t &tie) {
        if (members.size() <= i) {
            at.resize(i + 1);
            room.resize(i + 1);
            mode.resize(i + 1);
            members.resize(i + 1);
            valid.resize(i + 1, 0);
        }
        if (!valid[i] || !(2.0 * (q - at[i]).norm() < room[i])) gather(target, i, q, gate);
        rows.clear();
        d2.clear();
        tie = kNoTie;
        if (mode[i] == Mode::kNoPair) return 0;
        if (mode[i] == Mode::kTree) return target.nearestK(q, kNearest, rows, d2);
        tie = fromMembers(members[i], q, rows, d2);
        return static_cast<int>(rows.size());
    }

    // FLANN's answer from the members, up to the first tie among the k + 1 nearest (FLANN
    // orders tied points as its tree meets them) -> the position of the first of the tied
    // pair (kNoTie without one): positions from there on may differ from FLANN's.
    std::size_t fromMembers(const std::vector<Member> &ms, const Eigen::Vector3d &q,
                            std::vector<int> &rows, std::vector<float> &d2) {
        const float qx = static_cast<float>(q.x()), qy = static_cast<float>(q.y()),
                    qz = static_cast<float>(q.z());
        const std::size_t n = ms.size(), k = std::min<std::size_t>(kNearest, n);
        const std::size_t check = std::min(k + 1, n);
        // The `check` nearest in ascending order, by insertion (most members are farther than
        // the check-th so far and cost one comparison). Which of two equal distances is kept
        // or comes first is arbitrary, as with a sort: ties are reported below.
        sorted.clear();
        for (const auto &m : ms) {
            float r = 0.0f, d = qx - m.x;
            r += d * d;
            d = qy - m.y;
            r += d * d;
            d = qz - m.z;
            r += d * d;
            if (sorted.size() == check) {
                if (!(r < sorted.back().first)) continue;
                sorted.pop_back();
            }
            auto pos = sorted.end();
            while (pos != sorted.begin() && r < (pos - 1)->first) --pos;
            sorted.insert(pos, {r, m.index});
        }
        std::size_t tie = kNoTie;
        for (std::size_t j = 0; j + 1 < check && tie == kNoTie; ++j)
            if (!(sorted[j].first < sorted[j + 1].first)) tie = j;
        for (std::size_t j = 0; j < k; ++j) {
            rows.push_back(sorted[j].second);
            d2.push_back(sorted[j].first);
        }
        return tie;
    }
};

// The candidates of both feature kinds, shared by all rounds of a registration (and by the
// registrations of one StemCentreLmCache).
struct PairCandidates {
    VirtualCandidates centres;
    RealCandidates real;
};

// Stem-centre pairs: per virtual feature (source frame, current position qc in the target
// frame) the target point nearest to its circle in each angular sector.
void findVirtualPairs(const StemCentreTarget::Impl &target, const Points3 &centres,
                      const Eigen::VectorXd &radii, const Points3 &qc,
                      const StemCentreLmConfig &cfg, VirtualCandidates &candidates,
                      std::vector<VirtualPair> &vpairs) {
    vpairs.clear();
    const int sectors = std::max(1, cfg.virtual_sectors);
    const double gate = std::min(cfg.virtual_gate_m, cfg.virtual_max_gate_m);
    std::vector<int> best(static_cast<std::size_t>(sectors));
    std::vector<double> best_err(static_cast<std::size_t>(sectors));
    for (Eigen::Index i = 0; i < centres.rows(); ++i) {
        const Eigen::Vector3d c = centres.row(i).transpose();
        const Eigen::Vector3d q = qc.row(i).transpose();
        const double r = radii[i];
        std::fill(best.begin(), best.end(), -1);
        std::fill(best_err.begin(), best_err.end(), std::numeric_limits<double>::infinity());
        // |d - r| < gate only within this annulus of squared distances (a conservative bound:
        // the exact test follows), so most candidates cost no square root.
        const double inner = std::max(0.0, r - gate), outer = r + gate;
        const double in2 = inner * inner * (1.0 - 1e-9), out2 = outer * outer * (1.0 + 1e-9);
        const auto &members = candidates.near(target, static_cast<std::size_t>(i), q, r, cfg);
        const auto below =
            std::lower_bound(members.begin(), members.end(), q.z() - cfg.virtual_window_m,
                             [](const VirtualCandidates::Member &m, double z) { return m.z < z; });
        for (auto it = below; it != members.end() && it->z <= q.z() + cfg.virtual_window_m; ++it) {
            const auto &m = *it;
            if (std::abs(m.z - q.z()) > cfg.virtual_window_m) continue;
            const double dx = m.x - q.x(), dy = m.y - q.y();
            const double d2 = dx * dx + dy * dy;
            if (d2 >= out2 || d2 < in2) continue;
            const double err = std::abs(std::sqrt(d2) - r);
            if (err >= gate) continue;
            const int j = m.index;
            auto sector = static_cast<int>((std::atan2(dy, dx) + M_PI) / (2 * M_PI) * sectors);
            sector = std::min(std::max(sector, 0), sectors - 1);
            if (err < best_err[sector]) {
                best_err[sector] = err;
                best[sector] = j;
            }
        }
        const auto found =
            static_cast<int>(std::count_if(best.begin(), best.end(), [](int j) { return j >= 0; }));
        for (int j : best) {
            if (j >= 0) {
                vpairs.push_back(
                    {c, target.points.row(j).transpose(), r, cfg.virtual_weight / found, i});
            }
        }
    }
}

// The plane of a real feature at q through its nearest target points (rows idx, nearest first):
// the first two and the nearest that makes a non-degenerate triangle with them; true (and the
// pair) when q lies within the plane gate. `examined`: the last position looked at.
bool planeThrough(const StemCentreTarget::Impl &target, const std::vector<int> &idx,
                  const Eigen::Vector3d &s, const Eigen::Vector3d &q, Eigen::Index i,
                  const StemCentreLmConfig &cfg, PlanePair &pair, std::size_t &examined) {
    const Eigen::Vector3d p0 = target.points.row(idx[0]).transpose();
    const Eigen::Vector3d p1 = target.points.row(idx[1]).transpose();
    examined = idx.size() - 1;
    for (std::size_t k = 2; k < idx.size(); ++k) {
        const Eigen::Vector3d p2 = target.points.row(idx[k]).transpose();
        const Eigen::Vector3d cross = (p1 - p0).cross(p2 - p0);
        const double longest =
            std::max({(p1 - p0).squaredNorm(), (p2 - p0).squaredNorm(), (p2 - p1).squaredNorm()});
        if (longest <= 0.0 || cross.norm() / longest < cfg.min_triangle_ratio) continue;
        examined = k;
        const Eigen::Vector3d n = cross.normalized();
        pair = {s, p0, n, i};
        return std::abs(n.dot(q - p0)) <= cfg.plane_gate_m;
    }
    return false;
}

// Point-to-plane pairs: per real feature (source frame, current position qr in the target
// frame) the plane through its nearest non-collinear target points (FLANN's nearest: asked of
// the tree again when a tie among the cached ones reaches the positions the plane used).
void findPlanePairs(const StemCentreTarget::Impl &target, const Points3 &real, const Points3 &qr,
                    const StemCentreLmConfig &cfg, RealCandidates &candidates,
                    std::vector<PlanePair> &ppairs) {
    ppairs.clear();
    std::vector<int> idx;
    std::vector<float> d2;
    std::size_t tie = RealCandidates::kNoTie, examined = 0;
    PlanePair pair;
    for (Eigen::Index i = 0; i < real.rows(); ++i) {
        const Eigen::Vector3d s = real.row(i).transpose();
        const Eigen::Vector3d q = qr.row(i).transpose();
        const auto at = static_cast<std::size_t>(i);
        if (candidates.nearest(target, at, q, cfg.real_gate_m, idx, d2, tie) < 3) continue;
        if (std::sqrt(d2[0]) > cfg.real_gate_m) continue;  // d2[0] is FLANN's even on a tie
        bool found = planeThrough(target, idx, s, q, i, cfg, pair, examined);
        if (tie <= examined) {
            target.nearestK(q, RealCandidates::kNearest, idx, d2);
            found = planeThrough(target, idx, s, q, i, cfg, pair, examined);
        }
        if (found) ppairs.push_back(pair);
    }
}

// Features in the source frame with their current positions qc / qr in the target frame.
void findPairs(const StemCentreTarget::Impl &target, const Points3 &centres,
               const Eigen::VectorXd &radii, const Points3 &real, const Points3 &qc,
               const Points3 &qr, const StemCentreLmConfig &cfg, PairCandidates &candidates,
               std::vector<VirtualPair> &vpairs, std::vector<PlanePair> &ppairs) {
    findVirtualPairs(target, centres, radii, qc, cfg, candidates.centres, vpairs);
    findPlanePairs(target, real, qr, cfg, candidates.real, ppairs);
}

// The usable features (finite, centres with a positive radius, finite times when the in-sweep
// motion is estimated) with their times (zero when rigid).
struct LmFeatures {
    Points3 centres = Points3(0, 3);
    Eigen::VectorXd radii, centre_times;
    Points3 real = Points3(0, 3);
    Eigen::VectorXd real_times;
};

LmFeatures usableFeatures(const Eigen::Ref<const Points3> &virtual_centres,
                          const Eigen::Ref<const Eigen::VectorXd> &radii,
                          const Eigen::Ref<const Points3> &real_points, const SweepTimes *times) {
    const bool timed = times != nullptr;
    LmFeatures f;
    std::vector<int> keep;
    const Eigen::Index nv = virtual_centres.rows();
    for (Eigen::Index i = 0; i < nv; ++i) {
        if (virtual_centres.row(i).allFinite() && std::isfinite(radii[i]) && radii[i] > 0 &&
            (!timed || std::isfinite(times->centres[i])))
            keep.push_back(static_cast<int>(i));
    }
    f.centres = selectRows(virtual_centres, keep);
    const auto nk = static_cast<Eigen::Index>(keep.size());
    f.radii.resize(nk);
    f.centre_times = Eigen::VectorXd::Zero(nk);
    for (Eigen::Index k = 0; k < nk; ++k) {
        f.radii[k] = radii[keep[k]];
        if (timed) f.centre_times[k] = times->centres[keep[k]];
    }
    std::vector<int> keep_real;
    for (Eigen::Index i = 0; i < real_points.rows(); ++i) {
        if (real_points.row(i).allFinite() && (!timed || std::isfinite(times->real[i])))
            keep_real.push_back(static_cast<int>(i));
    }
    f.real = selectRows(real_points, keep_real);
    const auto nr = static_cast<Eigen::Index>(keep_real.size());
    f.real_times = Eigen::VectorXd::Zero(nr);
    for (Eigen::Index k = 0; timed && k < nr; ++k) f.real_times[k] = times->real[keep_real[k]];
    return f;
}

// The solution so far: the pose and the in-sweep coefficients (order rows), and the current
// positions of the features in the target frame (pose and in-sweep motion).
struct LmState {
    Eigen::Matrix4d T;
    Eigen::MatrixXd sweep;
    Points3 qc, qr;
};

void placeInto(const LmState &s, const Points3 &src, const Eigen::VectorXd &tau, Points3 &out) {
    const Eigen::Matrix3d R = s.T.block<3, 3>(0, 0);
    const Eigen::Vector3d t = s.T.block<3, 1>(0, 3);
    const auto order = static_cast<int>(s.sweep.rows());
    out.resize(src.rows(), 3);
    for (Eigen::Index i = 0; i < src.rows(); ++i) {
        Eigen::Vector3d q = R * src.row(i).transpose() + t;
        if (order > 0) {
            Eigen::Matrix<double, 6, 1> c = Eigen::Matrix<double, 6, 1>::Zero();
            double pw = tau[i];
            for (int k = 0; k < order; ++k) {
                c += pw * s.sweep.row(k).transpose();
                pw *= tau[i];
            }
            const Eigen::Vector3d w = c.tail<3>();
            const double angle = w.norm();
            if (angle > 0) q = Eigen::AngleAxisd(angle, w / angle) * (q - t) + t;
            q += c.head<3>();
        }
        out.row(i) = q.transpose();
    }
}

void placeFeatures(const LmFeatures &f, LmState &s) {
    placeInto(s, f.centres, f.centre_times, s.qc);
    placeInto(s, f.real, f.real_times, s.qr);
}

// Coarse to fine: the gates and the loss scale of a round (coarse_gate_factor shrinking by
// gate_decay per round down to 1x); returns the factor.
double roundConfig(const StemCentreLmConfig &config, int round, StemCentreLmConfig &out) {
    const double scale =
        std::max(1.0, config.coarse_gate_factor * std::pow(config.gate_decay, round));
    out = config;
    out.virtual_gate_m *= scale;
    out.real_gate_m *= scale;
    out.plane_gate_m *= scale;
    out.robust_scale_m *= scale;
    return scale;
}

// One LM solve over fixed pairs -> the perturbation [dt, dw] of the pose, then per order k of
// the in-sweep motion the perturbation of its coefficients (6 (order + 1) values).
std::vector<double> solveRound(const std::vector<VirtualPair> &vpairs,
                               const std::vector<PlanePair> &ppairs, const LmFeatures &f,
                               const LmState &s, const StemCentreLmConfig &config,
                               double robust_scale_m) {
    const auto order = static_cast<int>(s.sweep.rows());
    std::vector<double> delta(static_cast<std::size_t>(6 * (order + 1)), 0.0);
    ceres::Problem problem;
    if (order == 0) {
        problem.AddResidualBlock(new PairsCost(vpairs, ppairs, s.T, robust_scale_m), nullptr,
                                 delta.data());
    } else {
        const Eigen::Vector3d o = s.T.block<3, 1>(0, 3);
        problem.AddResidualBlock(new SweepPairsCost(vpairs, ppairs, s.qc, s.qr, f.centre_times,
                                                    f.real_times, o, order, robust_scale_m),
                                 nullptr, delta.data());
        problem.AddResidualBlock(
            new SweepPriorCost(s.sweep, config.sweep_prior_tau_s, config.sweep_prior_m,
                               config.sweep_prior_rad, config.robust_scale_m),
            nullptr, delta.data());
    }
    ceres::Solver::Options options;
    options.minimizer_type = ceres::TRUST_REGION;
    options.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
    options.linear_solver_type = ceres::DENSE_QR;
    options.max_num_iterations = config.max_solver_iterations;
    options.num_threads = 1;
    options.logging_type = ceres::SILENT;
    ceres::Solver::Summary summary;
    ceres::Solve(options, &problem, &summary);
    return delta;
}

// Applies a round's perturbation to the state; true when the step is below the convergence
// thresholds (the pose step as seen from the sensor, independent of where the target origin
// lies, and each in-sweep coefficient's change at the prior time).
bool applyStep(const std::vector<double> &delta, const StemCentreLmConfig &config, LmState &s) {
    const auto order = static_cast<int>(s.sweep.rows());
    const Eigen::Matrix4d T_before = s.T;
    const Eigen::Vector3d dw(delta[3], delta[4], delta[5]);
    const double angle = dw.norm();
    Eigen::Matrix3d dR = Eigen::Matrix3d::Identity();
    if (angle > 0) dR = Eigen::AngleAxisd(angle, dw / angle).toRotationMatrix();
    const Eigen::Vector3d dt(delta[0], delta[1], delta[2]);
    s.T.block<3, 3>(0, 0) = dR * T_before.block<3, 3>(0, 0);
    // Rigid: a left perturbation; with the in-sweep motion, about the sensor position.
    s.T.block<3, 1>(0, 3) = (order == 0 ? Eigen::Vector3d(dR * T_before.block<3, 1>(0, 3))
                                        : Eigen::Vector3d(T_before.block<3, 1>(0, 3))) +
                            dt;
    double sweep_step = 0.0;  // largest in-sweep change at the prior time, in threshold units
    for (int k = 1; k <= order; ++k) {
        double mt = 0.0, mr = 0.0;
        for (int c = 0; c < 6; ++c) {
            const double d = delta[static_cast<std::size_t>(6 * k + c)];
            s.sweep(k - 1, c) += d;
            (c < 3 ? mt : mr) += d * d;
        }
        const double pw = std::pow(config.sweep_prior_tau_s, k);
        sweep_step = std::max({sweep_step, std::sqrt(mt) * pw / config.converged_translation_m,
                               std::sqrt(mr) * pw / config.converged_rotation_rad});
    }
    const Eigen::Matrix4d step = T_before.inverse() * s.T;
    return step.block<3, 1>(0, 3).norm() < config.converged_translation_m &&
           angle < config.converged_rotation_rad && sweep_step < 1.0;
}

// Correspondence rounds (pairs renewed, then one LM solve) until converged at the fine
// gates, too few pairs, or max_rounds.
void iterateRounds(const StemCentreTarget::Impl &target, const LmFeatures &f,
                   const StemCentreLmConfig &config, PairCandidates &candidates, LmState &s,
                   StemCentreLmResult &result) {
    std::vector<VirtualPair> vpairs;
    std::vector<PlanePair> ppairs;
    StemCentreLmConfig round_cfg;
    for (int round = 0; round < config.max_rounds; ++round) {
        const double scale = roundConfig(config, round, round_cfg);
        placeFeatures(f, s);
        findPairs(target, f.centres, f.radii, f.real, s.qc, s.qr, round_cfg, candidates, vpairs,
                  ppairs);
        result.iterations = round + 1;
        if (static_cast<int>(vpairs.size() + ppairs.size()) < config.min_inliers) break;
        const auto delta = solveRound(vpairs, ppairs, f, s, config, round_cfg.robust_scale_m);
        if (applyStep(delta, config, s) && scale <= 1.0) {
            result.converged = true;
            break;
        }
    }
}

Eigen::Matrix4d orthonormalised(const Eigen::Matrix4d &T) {
    Eigen::Matrix4d out = T;
    out.block<3, 3>(0, 0) =
        Eigen::Quaterniond(Eigen::Matrix3d(T.block<3, 3>(0, 0))).normalized().toRotationMatrix();
    return out;
}

// One pair at the solution: transformed point q, residual direction, raw residual and its
// Cauchy IRLS weight (times the pair's own weight).
struct PairAtSolution {
    Eigen::Vector3d q, dir;
    double residual, weight;
};

// Pair statistics at the solution (inliers, RMS per feature kind, rmse) -> the pairs.
std::vector<PairAtSolution> pairStatistics(const std::vector<VirtualPair> &vpairs,
                                           const std::vector<PlanePair> &ppairs, const LmState &s,
                                           const StemCentreLmConfig &config,
                                           StemCentreLmResult &result) {
    std::vector<PairAtSolution> pairs;
    pairs.reserve(vpairs.size() + ppairs.size());
    auto add = [&](const Eigen::Vector3d &q, const Eigen::Vector3d &dir, double r, double w) {
        const double u = r / config.robust_scale_m;
        pairs.push_back({q, dir, r, w / (1.0 + u * u)});
    };
    double vsum = 0.0, psum = 0.0;
    for (const auto &v : vpairs) {
        const Eigen::Vector3d q = s.qc.row(v.index).transpose();
        const Eigen::Vector3d d(q.x() - v.target.x(), q.y() - v.target.y(), 0.0);
        const double dn = std::max(d.norm(), 1e-9);
        const double r = dn - v.radius;
        vsum += r * r;
        add(q, d / dn, r, v.weight);
    }
    for (const auto &p : ppairs) {
        const Eigen::Vector3d q = s.qr.row(p.index).transpose();
        const double r = p.normal.dot(q - p.origin);
        psum += r * r;
        add(q, p.normal, r, 1.0);
    }
    result.virtual_inliers = static_cast<int>(vpairs.size());
    result.real_inliers = static_cast<int>(ppairs.size());
    result.inliers = result.virtual_inliers + result.real_inliers;
    result.virtual_rms_m = vpairs.empty() ? 0.0 : std::sqrt(vsum / vpairs.size());
    result.real_rms_m = ppairs.empty() ? 0.0 : std::sqrt(psum / ppairs.size());
    result.rmse =
        pairs.empty() ? 0.0 : std::sqrt((vsum + psum) / static_cast<double>(pairs.size()));
    return pairs;
}

// Covariance (Gauss-Newton information for a left perturbation [dt, dw], d q / d dw = -[q]x,
// scaled by the residual variance) and the degeneracy test on the same information about the
// centroid with rotation scaled by the feature spread (independent of where the frame origin
// lies and of units).
void covarianceAndDegeneracy(const std::vector<PairAtSolution> &pairs,
                             const StemCentreLmConfig &config, StemCentreLmResult &result) {
    const std::size_t m = pairs.size();
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (const auto &p : pairs) centroid += p.q;
    centroid /= static_cast<double>(m);
    double spread = 0.0;
    for (const auto &p : pairs) spread += (p.q - centroid).squaredNorm();
    spread = std::max(std::sqrt(spread / m), 1e-6);
    Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 6> Hn = Eigen::Matrix<double, 6, 6>::Zero();
    double wr2 = 0.0, wsum = 0.0;
    for (const auto &p : pairs) {
        Eigen::Matrix<double, 1, 6> J, Jn;
        J << p.dir.transpose(), p.q.cross(p.dir).transpose();
        Jn << p.dir.transpose(), (p.q - centroid).cross(p.dir).transpose() / spread;
        H += p.weight * J.transpose() * J;
        Hn += p.weight * Jn.transpose() * Jn;
        wr2 += p.weight * p.residual * p.residual;
        wsum += p.weight;
    }
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> eig(Hn);
    const double emax = eig.eigenvalues().maxCoeff();
    const double emin = eig.eigenvalues().minCoeff();
    result.degenerate = !(emax > 0.0) || emin / emax < config.degenerate_eigen_ratio;
    const double dof = std::max(1.0, static_cast<double>(m) - 6.0);
    const double sigma2 = std::max(wr2 / wsum * m / dof, 1e-8);
    const Eigen::FullPivLU<Eigen::Matrix<double, 6, 6>> lu(H);
    if (lu.isInvertible()) {
        result.covariance = sigma2 * lu.inverse();
    } else {
        result.covariance = Matrix6d::Identity() * kUnobservedVariance;
        result.degenerate = true;
    }
}

// Statistics and covariance at the solution, with pairs renewed at the fine gates.
void assessSolution(const StemCentreTarget::Impl &target, const LmFeatures &f,
                    const StemCentreLmConfig &config, PairCandidates &candidates, LmState &s,
                    StemCentreLmResult &result) {
    std::vector<VirtualPair> vpairs;
    std::vector<PlanePair> ppairs;
    placeFeatures(f, s);
    findPairs(target, f.centres, f.radii, f.real, s.qc, s.qr, config, candidates, vpairs, ppairs);
    const auto pairs = pairStatistics(vpairs, ppairs, s, config, result);
    if (result.inliers < config.min_inliers) {
        result.converged = false;
        return;
    }
    covarianceAndDegeneracy(pairs, config, result);
}

}  // namespace

// The candidates of the last registration, the target they came from and its features.
struct StemCentreLmCache::Impl {
    std::uint64_t target_id = 0;
    LmFeatures features;
    PairCandidates candidates;

    // The candidates for these features on this target: the kept ones when both are the same
    // as last time, else a fresh set.
    PairCandidates &candidatesFor(const StemCentreTarget::Impl &target, const LmFeatures &f) {
        const auto same = [](const auto &a, const auto &b) {
            return a.rows() == b.rows() && a.cols() == b.cols() && a == b;
        };
        if (target.id != target_id || !same(f.centres, features.centres) ||
            !same(f.radii, features.radii) || !same(f.real, features.real)) {
            candidates = PairCandidates();
            target_id = target.id;
            features = f;
        }
        return candidates;
    }
};

StemCentreLmCache::StemCentreLmCache() : impl_(std::make_unique<Impl>()) {}
StemCentreLmCache::~StemCentreLmCache() = default;

StemCentreLmResult registerStemCentreLm(const StemCentreTarget &target,
                                        const Eigen::Ref<const Points3> &virtual_centres,
                                        const Eigen::Ref<const Eigen::VectorXd> &radii,
                                        const Eigen::Ref<const Points3> &real_points,
                                        const Pose3 &T_initial, const StemCentreLmConfig &config,
                                        const SweepTimes *times, StemCentreLmCache *cache) {
    const int order = std::max(0, config.sweep_order);
    if (order > 0 && (times == nullptr || times->centres.size() != virtual_centres.rows() ||
                      times->real.size() != real_points.rows()))
        throw std::invalid_argument(
            "sweep_order > 0 needs one time per virtual centre and one per real feature");
    if (radii.size() != virtual_centres.rows())
        throw std::invalid_argument("registerStemCentreLm: " + std::to_string(radii.size()) +
                                    " radii for " + std::to_string(virtual_centres.rows()) +
                                    " virtual centres");
    if (!T_initial.matrix().allFinite())
        throw std::invalid_argument("registerStemCentreLm: T_initial is not finite");
    StemCentreLmResult result;
    result.T_target_source = T_initial;
    if (target.size() < 3) return result;

    const LmFeatures features =
        usableFeatures(virtual_centres, radii, real_points, order > 0 ? times : nullptr);
    LmState state{T_initial.matrix(), Eigen::MatrixXd::Zero(order, 6), {}, {}};
    PairCandidates own;  // target points near each feature, shared by all rounds
    PairCandidates &candidates =
        cache != nullptr ? cache->impl().candidatesFor(target.impl(), features) : own;
    iterateRounds(target.impl(), features, config, candidates, state, result);
    state.T = orthonormalised(state.T);  // the left updates accumulate rounding
    result.T_target_source = Pose3(state.T);
    result.sweep = state.sweep;
    assessSolution(target.impl(), features, config, candidates, state, result);
    return result;
}

}  // namespace forestslam::registration
