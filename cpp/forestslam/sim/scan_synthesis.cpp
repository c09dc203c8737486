#include "forestslam/sim/scan_synthesis.hpp"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <utility>
#include <vector>

namespace forestslam::sim {

namespace {

// Standard normal quantile of p in (0, 1) (Acklam's rational approximation, absolute error
// below 1e-8): one uniform per normal draw, and no logarithm for 95 % of them.
double normalQuantile(double p) {
    constexpr double a[6] = {-3.969683028665376e+01, 2.209460984245205e+02,  -2.759285104469687e+02,
                             1.383577518672690e+02,  -3.066479806614716e+01, 2.506628277459239e+00};
    constexpr double b[5] = {-5.447609879822406e+01, 1.615858368580409e+02, -1.556989798598866e+02,
                             6.680131188771972e+01, -1.328068155288572e+01};
    constexpr double c[6] = {-7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e+00,
                             -2.549732539343734e+00, 4.374664141464968e+00,  2.938163982698783e+00};
    constexpr double d[4] = {7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e+00,
                             3.754408661907416e+00};
    constexpr double p_low = 0.02425;
    auto tail = [&](double q) {
        return (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
               ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1.0);
    };
    if (p < p_low) return tail(std::sqrt(-2.0 * std::log(p)));
    if (p > 1.0 - p_low) return -tail(std::sqrt(-2.0 * std::log(1.0 - p)));
    const double q = p - 0.5, r = q * q;
    return (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q /
           (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1.0);
}

constexpr uint64_t kDropoutSalt = 11, kRangeSalt = 13, kIntensitySalt = 17;

// One reflectance draw per object (a tree's bark, a crown clump, a log), fixed for the run.
double objectReflectanceNoise(uint8_t surface, int32_t object, const ScanModel &model) {
    return normalQuantile(hashUniform(mixKey(model.object_seed, surface),
                                      static_cast<uint64_t>(static_cast<int64_t>(object))));
}

// Range fall-off of the intensity (reference / range)^exponent beyond the reference range and
// the near-range loss, the fall-off tabulated every 0.25 m and interpolated linearly (relative
// error below 1e-4; no pow per return).
class RangeGain {
  public:
    explicit RangeGain(const ScanModel &model) : model_(model) {
        if (model.range_exponent == 0.0) return;
        const double span = std::max(model.range_max_m - model.reference_range_m, 0.0);
        table_.resize(static_cast<size_t>(std::ceil(span / kStep)) + 2);
        for (size_t k = 0; k < table_.size(); ++k)
            table_[k] = std::pow(model.reference_range_m / (model.reference_range_m + k * kStep),
                                 model.range_exponent);
    }
    double operator()(double range) const {
        double gain = 1.0;
        if (!table_.empty() && range > model_.reference_range_m) {
            const double x = std::min((range - model_.reference_range_m) / kStep,
                                      static_cast<double>(table_.size() - 1));
            const size_t k = std::min(static_cast<size_t>(x), table_.size() - 2);
            gain = table_[k] + (x - k) * (table_[k + 1] - table_[k]);
        }
        if (range < model_.near_range_m) gain *= 0.5 + 0.5 * range / model_.near_range_m;
        return gain;
    }

  private:
    static constexpr double kStep = 0.25;
    const ScanModel &model_;
    std::vector<double> table_;
};

float intensityOf(uint8_t surface, double object_noise, double range_gain, double cos_incidence,
                  double noise, const ScanModel &model) {
    const Material &m = model.materials[surface < kSurfaceCount ? surface : uint8_t{0}];
    double value = m.median * std::exp(m.sigma_object * object_noise + m.sigma_return * noise);
    const double c = std::clamp(cos_incidence, 0.0, 1.0);
    if (m.incidence_exponent == 1.0)
        value *= c;
    else if (m.incidence_exponent == 0.5)
        value *= std::sqrt(c);
    else if (m.incidence_exponent != 0.0)
        value *= std::pow(c, m.incidence_exponent);
    value *= range_gain;
    return static_cast<float>(std::round(std::clamp(value, 0.0, 255.0)));
}

}  // namespace

float returnIntensity(uint8_t surface, int32_t object, double range, double cos_incidence,
                      double noise, const ScanModel &model) {
    return intensityOf(surface, objectReflectanceNoise(surface, object, model),
                       RangeGain(model)(range), cos_incidence, noise, model);
}

double dropoutProbability(double range, double cos_incidence, const ScanModel &model) {
    double keep = 1.0 - model.dropout_rate;
    if (cos_incidence < model.grazing_cos) keep *= std::max(cos_incidence, 0.0) / model.grazing_cos;
    const double far = model.far_fraction * model.range_max_m;
    if (range > far && model.range_max_m > far)
        keep *= std::max(0.0, (model.range_max_m - range) / (model.range_max_m - far));
    return 1.0 - keep;
}

double rangeSigma(double range, double cos_incidence, const ScanModel &model) {
    if (model.beam_divergence_rad <= 0.0) return model.range_noise_m;
    // tan(incidence) capped at 10 (84 deg): beyond, the return is mostly lost anyway.
    const double c = std::clamp(cos_incidence, 0.0995, 1.0);
    const double footprint = 0.5 * model.beam_divergence_rad * range * std::sqrt(1.0 - c * c) / c;
    return std::sqrt(model.range_noise_m * model.range_noise_m + footprint * footprint);
}

namespace {

void checkSynthesisInputs(const Eigen::Ref<const Eigen::VectorXd> &knot_time,
                          const Eigen::Ref<const PoseRows> &knot_pose,
                          const Eigen::Ref<const Eigen::VectorXd> &group_time,
                          const Eigen::Ref<const IndexVector> &group, Eigen::Index n_dirs) {
    const Eigen::Index m = knot_time.size();
    if (m == 0 || knot_pose.rows() != m)
        throw std::invalid_argument("need one pose (16 values) per knot time, at least one");
    if (group.size() != n_dirs) throw std::invalid_argument("need one group index per direction");
    for (Eigen::Index k = 1; k < m; ++k)
        if (!(knot_time[k] > knot_time[k - 1]))
            throw std::invalid_argument("knot times must increase");
    if (!knot_time.allFinite() || !knot_pose.allFinite() || !group_time.allFinite())
        throw std::invalid_argument("knot times, poses and group times must be finite");
    if (n_dirs > 0 && (group.minCoeff() < 0 || group.maxCoeff() >= group_time.size()))
        throw std::invalid_argument("group index out of range");
}

// The sensor pose (rotation, position in the world) from which each group of rays is fired.
struct GroupPoses {
    std::vector<Eigen::Matrix3d> rot;
    std::vector<Eigen::Vector3d> pos;
};

// Rotation and position of knot k: row k of knot_pose is T_world_sensor, row-major.
void knotPose(const Eigen::Ref<const PoseRows> &knot_pose, Eigen::Index k, Eigen::Matrix3d &r,
              Eigen::Vector3d &p) {
    const auto row = knot_pose.row(k);
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) r(i, j) = row(4 * i + j);
        p[i] = row(4 * i + 3);
    }
}

std::vector<Eigen::Quaterniond> knotQuaternions(const Eigen::Ref<const PoseRows> &knot_pose) {
    std::vector<Eigen::Quaterniond> knot_q(static_cast<size_t>(knot_pose.rows()));
    for (Eigen::Index k = 0; k < knot_pose.rows(); ++k) {
        Eigen::Matrix3d r;
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j) r(i, j) = knot_pose(k, 4 * i + j);
        knot_q[static_cast<size_t>(k)] = Eigen::Quaterniond(r).normalized();
    }
    return knot_q;
}

// The knot segment [seg, seg + 1] holding t, strictly inside the knot times. The search goes on
// from the previous group's segment: group times usually increase.
Eigen::Index findSegment(const Eigen::Ref<const Eigen::VectorXd> &knot_time, double t,
                         Eigen::Index seg) {
    if (t < knot_time[seg]) seg = 0;
    while (knot_time[seg + 1] < t) ++seg;
    return seg;
}

// The pose the fraction a (0 < a < 1) of the way from knot seg to knot seg + 1. Knots are about
// 1 ms apart, so the rotation changes by well under a milliradian between them, where normalised
// linear interpolation of quaternions equals slerp.
void interpolateKnots(const Eigen::Ref<const PoseRows> &knot_pose,
                      const std::vector<Eigen::Quaterniond> &knot_q, Eigen::Index seg, double a,
                      Eigen::Matrix3d &r, Eigen::Vector3d &p) {
    Eigen::Matrix3d r0, r1;
    Eigen::Vector3d p0, p1;
    knotPose(knot_pose, seg, r0, p0);
    knotPose(knot_pose, seg + 1, r1, p1);
    p = (1.0 - a) * p0 + a * p1;
    const Eigen::Quaterniond &q0 = knot_q[static_cast<size_t>(seg)];
    const Eigen::Quaterniond &q1 = knot_q[static_cast<size_t>(seg) + 1];
    const double sign = q0.dot(q1) < 0.0 ? -1.0 : 1.0;
    Eigen::Quaterniond q;
    q.coeffs() = (1.0 - a) * q0.coeffs() + (sign * a) * q1.coeffs();
    r = q.normalized().toRotationMatrix();
}

// Pose of every group: a knot's own pose at a knot time or outside the knots (clamped), else
// interpolated between its two knots.
GroupPoses interpolateGroupPoses(const Eigen::Ref<const Eigen::VectorXd> &knot_time,
                                 const Eigen::Ref<const PoseRows> &knot_pose,
                                 const Eigen::Ref<const Eigen::VectorXd> &group_time) {
    const Eigen::Index m = knot_time.size(), g_count = group_time.size();
    const std::vector<Eigen::Quaterniond> knot_q = knotQuaternions(knot_pose);
    GroupPoses poses{std::vector<Eigen::Matrix3d>(static_cast<size_t>(g_count)),
                     std::vector<Eigen::Vector3d>(static_cast<size_t>(g_count))};
    Eigen::Index seg = 0;
    for (Eigen::Index g = 0; g < g_count; ++g) {
        const double t = group_time[g];
        Eigen::Matrix3d &r = poses.rot[static_cast<size_t>(g)];
        Eigen::Vector3d &p = poses.pos[static_cast<size_t>(g)];
        if (t <= knot_time[0]) {
            knotPose(knot_pose, 0, r, p);
            continue;
        }
        if (t >= knot_time[m - 1]) {
            knotPose(knot_pose, m - 1, r, p);
            continue;
        }
        seg = findSegment(knot_time, t, seg);
        if (t == knot_time[seg])
            knotPose(knot_pose, seg, r, p);
        else if (t == knot_time[seg + 1])
            knotPose(knot_pose, seg + 1, r, p);
        else
            interpolateKnots(knot_pose, knot_q, seg,
                             (t - knot_time[seg]) / (knot_time[seg + 1] - knot_time[seg]), r, p);
    }
    return poses;
}

// Per-object reflectance draws, made once per object seen in a scan (a scan sees the same
// stems and crowns thousands of times; each draw is a hash and a normal quantile).
class ObjectNoiseCache {
  public:
    explicit ObjectNoiseCache(const ScanModel &model) : model_(model) {}
    double operator()(uint8_t surface, int32_t object) {
        if (surface >= kSurfaceCount || object < 0)
            return objectReflectanceNoise(surface, object, model_);
        std::vector<double> &cache = noise_[surface];
        if (static_cast<size_t>(object) >= cache.size())
            cache.resize(static_cast<size_t>(object) + 1, std::nan(""));
        double &v = cache[static_cast<size_t>(object)];
        if (std::isnan(v)) v = objectReflectanceNoise(surface, object, model_);
        return v;
    }

  private:
    const ScanModel &model_;
    std::vector<double> noise_[kSurfaceCount];
};

// Rays are cast in chunks of a few thousand: they stay in cache, and memory does not grow with a
// TLS station's millions of rays. A chunk ends at a group boundary when one comes within the
// slack, so that rays sharing a pose share their grid walk (ForestScene::castBatch gives the
// same hits as one by one, wherever a chunk ends).
constexpr Eigen::Index kChunk = 2048, kChunkSlack = 256;

Eigen::Index chunkEnd(const Eigen::Ref<const IndexVector> &group, Eigen::Index begin) {
    const Eigen::Index n = group.size();
    Eigen::Index end = std::min(n, begin + kChunk);
    while (end < n && end - begin < kChunk + kChunkSlack && group[end] == group[end - 1]) ++end;
    return end;
}

// The scan being synthesized, chunk by chunk: world rays from the group poses, their first hits,
// then per hit the sensor's measurement (dropout, range noise, intensity) into the output.
class ScanSynthesis {
  public:
    ScanSynthesis(const ForestScene &scene, const GroupPoses &poses,
                  const Eigen::Ref<const IndexVector> &group,
                  const Eigen::Ref<const Points3> &local_dirs, const ScanModel &model,
                  uint64_t cast_seed, uint64_t noise_seed)
        : scene_(scene),
          poses_(poses),
          group_(group),
          local_dirs_(local_dirs),
          model_(model),
          cast_seed_(cast_seed),
          noise_seed_(noise_seed),
          range_gain_(model),
          object_noise_(model) {
        const Eigen::Index n = local_dirs.rows();
        out_.ray.resize(n);
        out_.points.resize(n, 3);
        out_.intensity.resize(n);
        out_.surface.resize(n);
        out_.object.resize(n);
        rays_.reserve(kChunk + kChunkSlack);
    }

    void addChunk(Eigen::Index begin, Eigen::Index end) {
        worldRays(begin, end);
        hits_.resize(rays_.size());
        scene_.castBatch(rays_.data(), rays_.size(), hits_.data());
        for (size_t q = 0; q < rays_.size(); ++q) measure(hits_[q], rows_[q], norms_[q]);
    }

    SynthesizedScan finish() {
        out_.ray.conservativeResize(kept_);
        out_.points.conservativeResize(kept_, 3);
        out_.intensity.conservativeResize(kept_);
        out_.surface.conservativeResize(kept_);
        out_.object.conservativeResize(kept_);
        return std::move(out_);
    }

  private:
    // The world rays of rows [begin, end), unit length, with the row and the length of its
    // sensor-frame direction; rows with a zero or non-finite direction are left out.
    void worldRays(Eigen::Index begin, Eigen::Index end) {
        rays_.clear();
        rows_.clear();
        norms_.clear();
        for (Eigen::Index i = begin; i < end; ++i) {
            const Eigen::Vector3d local = local_dirs_.row(i).transpose();
            const size_t g = static_cast<size_t>(group_[i]);
            Ray ray;
            ray.origin = poses_.pos[g];
            ray.dir = poses_.rot[g] * local;
            const double norm = ray.dir.norm();
            if (!(norm > 0.0) || !std::isfinite(norm)) continue;
            ray.dir /= norm;
            ray.t_min = 0.0;  // anything closer than range_min still blocks the beam
            ray.t_max = model_.range_max_m;
            ray.key = mixKey(cast_seed_, static_cast<uint64_t>(i));
            rays_.push_back(ray);
            rows_.push_back(i);
            norms_.push_back(norm);
        }
    }

    // The return of row i from its first hit, unless it is too close or dropped: the range with
    // noise, along the row's own sensor-frame direction, and its intensity. Every draw is a hash
    // of (noise_seed, i).
    void measure(const Hit &hit, Eigen::Index i, double norm) {
        if (!hit.valid() || hit.t < model_.range_min_m) return;
        const uint64_t key = mixKey(noise_seed_, static_cast<uint64_t>(i));
        const double p_lost = dropoutProbability(hit.t, hit.cos_incidence, model_);
        if (p_lost > 0.0 && hashUniform(key, kDropoutSalt) < p_lost) return;
        const double range = hit.t + rangeSigma(hit.t, hit.cos_incidence, model_) *
                                         normalQuantile(hashUniform(key, kRangeSalt));
        const double intensity_noise = normalQuantile(hashUniform(key, kIntensitySalt));
        out_.ray[kept_] = i;
        out_.points.row(kept_) = (range / norm) * local_dirs_.row(i);
        out_.intensity[kept_] =
            intensityOf(hit.surface, object_noise_(hit.surface, hit.object), range_gain_(hit.t),
                        hit.cos_incidence, intensity_noise, model_);
        out_.surface[kept_] = hit.surface;
        out_.object[kept_] = hit.object;
        ++kept_;
    }

    const ForestScene &scene_;
    const GroupPoses &poses_;
    const Eigen::Ref<const IndexVector> &group_;
    const Eigen::Ref<const Points3> &local_dirs_;
    const ScanModel &model_;
    const uint64_t cast_seed_, noise_seed_;
    const RangeGain range_gain_;
    ObjectNoiseCache object_noise_;
    SynthesizedScan out_;
    Eigen::Index kept_ = 0;
    std::vector<Ray> rays_;  // the current chunk's rays, their rows, direction lengths, hits
    std::vector<Eigen::Index> rows_;
    std::vector<double> norms_;
    std::vector<Hit> hits_;
};

}  // namespace

SynthesizedScan synthesizeScan(const ForestScene &scene,
                               const Eigen::Ref<const Eigen::VectorXd> &knot_time,
                               const Eigen::Ref<const PoseRows> &knot_pose,
                               const Eigen::Ref<const Eigen::VectorXd> &group_time,
                               const Eigen::Ref<const IndexVector> &group,
                               const Eigen::Ref<const Points3> &local_dirs, const ScanModel &model,
                               uint64_t cast_seed, uint64_t noise_seed) {
    checkSynthesisInputs(knot_time, knot_pose, group_time, group, local_dirs.rows());
    const GroupPoses poses = interpolateGroupPoses(knot_time, knot_pose, group_time);
    ScanSynthesis synthesis(scene, poses, group, local_dirs, model, cast_seed, noise_seed);
    for (Eigen::Index begin = 0; begin < local_dirs.rows();) {
        const Eigen::Index end = chunkEnd(group, begin);
        synthesis.addChunk(begin, end);
        begin = end;
    }
    return synthesis.finish();
}

}  // namespace forestslam::sim
