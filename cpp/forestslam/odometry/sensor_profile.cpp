#include "forestslam/odometry/sensor_profile.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <set>
#include <stdexcept>

namespace forestslam::odometry {
namespace {

namespace fs = std::filesystem;
constexpr double kDeg = M_PI / 180.0;

const std::set<std::string> kKeys = {
    "name", "kind", "channels", "vertical_fov_deg", "horizontal_fov_deg", "azimuth_resolution_deg",
    "rate_hz", "range_min_m", "range_max_m", "range_noise_m", "dropout_rate", "image_rows",
    "image_cols", "intensity_threshold", "vertical_angles_deg",
    // raw-packet decoding (the Python readers); not used here
    "packet_model", "cut_angle_deg"};

class ProfileReader {
  public:
    ProfileReader(const YAML::Node &doc, std::string where) : doc_(doc), where_(std::move(where)) {}

    template <typename T>
    T get(const std::string &key) const {
        const YAML::Node node = doc_[key];
        if (!node) fail("missing key '" + key + "'");
        try {
            return node.as<T>();
        } catch (const YAML::Exception &) {
            fail("key '" + key + "' has a value of the wrong type");
        }
        return T{};
    }
    bool has(const std::string &key) const { return doc_[key] && !doc_[key].IsNull(); }
    [[noreturn]] void fail(const std::string &what) const {
        throw std::invalid_argument(where_ + ": " + what);
    }

  private:
    const YAML::Node &doc_;
    std::string where_;
};

std::vector<double> verticalAnglesRad(const ProfileReader &r, int channels) {
    std::vector<double> deg;
    if (r.has("vertical_angles_deg")) {
        deg = r.get<std::vector<double>>("vertical_angles_deg");
        if (static_cast<int>(deg.size()) != channels)
            r.fail("vertical_angles_deg must list " + std::to_string(channels) + " angles");
        std::sort(deg.begin(), deg.end());
    } else if (channels > 0) {
        const auto fov = r.get<std::vector<double>>("vertical_fov_deg");
        if (fov.size() != 2 || !(fov[0] <= fov[1])) r.fail("vertical_fov_deg must be [low, high]");
        for (int i = 0; i < channels; ++i)
            deg.push_back(channels == 1 ? fov[0]
                                        : fov[0] + (fov[1] - fov[0]) * i / double(channels - 1));
    }
    for (double &a : deg) a *= kDeg;
    return deg;
}

}  // namespace

SensorProfile loadSensorProfile(const std::string &path) {
    YAML::Node doc;
    try {
        doc = YAML::LoadFile(path);
    } catch (const YAML::BadFile &) {
        throw std::invalid_argument(path + ": sensor profile file not found or unreadable");
    } catch (const YAML::Exception &e) {
        throw std::invalid_argument(path + ": not valid YAML (" + e.msg + ")");
    }
    if (!doc.IsMap()) throw std::invalid_argument(path + ": a sensor profile must be a mapping");
    const ProfileReader r(doc, path);
    for (const auto &item : doc) {
        const auto key = item.first.as<std::string>();
        if (!kKeys.count(key)) r.fail("unknown key '" + key + "'");
    }
    SensorProfile p;
    p.name = r.get<std::string>("name");
    p.rate_hz = r.get<double>("rate_hz");
    OdometrySensor &s = p.sensor;
    s.kind = r.get<std::string>("kind");
    if (s.kind != "spinning" && s.kind != "solid_state" && s.kind != "tls" && s.kind != "map")
        r.fail("kind '" + s.kind + "' unknown; choose one of spinning, solid_state, tls, map");
    const bool scanning = s.kind == "spinning" || s.kind == "solid_state";
    const int channels = r.get<int>("channels");
    if (channels < (scanning ? 1 : 0)) r.fail("channels must be >= 1");
    if (scanning && !(p.rate_hz > 0)) r.fail("rate_hz must be > 0");
    if (p.rate_hz > 100) r.fail("rate_hz must be <= 100 (sweeps per second)");
    auto &g = s.geometry;
    g.image_rows = r.get<int>("image_rows");
    g.image_cols = r.get<int>("image_cols");
    if (g.image_rows < 0 || g.image_cols < 0) r.fail("image size must be >= 0");
    g.has_range_image = scanning && g.image_rows > 0;
    const double hfov = r.get<double>("horizontal_fov_deg");
    if (!(hfov > 0 && hfov <= 360)) r.fail("horizontal_fov_deg must be in (0, 360]");
    g.horizontal_fov_rad = hfov * kDeg;
    const double azimuth = r.get<double>("azimuth_resolution_deg");
    if (!(azimuth > 0)) r.fail("azimuth_resolution_deg must be > 0");
    g.azimuth_step_rad = azimuth * kDeg;
    g.vertical_angles_rad = verticalAnglesRad(r, channels);
    const auto &v = g.vertical_angles_rad;
    g.theta_v_rad = v.size() < 2 ? azimuth * kDeg : (v.back() - v.front()) / double(v.size() - 1);
    if (r.has("intensity_threshold")) s.intensity_threshold = r.get<double>("intensity_threshold");
    return p;
}

SensorProfile findSensorProfile(const std::string &name_or_path,
                                const std::vector<std::string> &folders) {
    const fs::path path(name_or_path);
    if (path.extension() == ".yaml" || path.extension() == ".yml" || fs::is_regular_file(path))
        return loadSensorProfile(name_or_path);
    std::string shipped;
    for (const auto &folder : folders) {
        const fs::path file = fs::path(folder) / (name_or_path + ".yaml");
        if (fs::is_regular_file(file)) return loadSensorProfile(file.string());
        std::error_code ec;
        for (const auto &entry : fs::directory_iterator(folder, ec))
            if (entry.path().extension() == ".yaml")
                shipped += (shipped.empty() ? "" : ", ") + entry.path().stem().string();
    }
    throw std::invalid_argument("unknown sensor '" + name_or_path +
                                "'; shipped: " + (shipped.empty() ? "none found" : shipped) +
                                " (or give a profile YAML file)");
}

}  // namespace forestslam::odometry
