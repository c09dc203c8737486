#include "forestslam/registration/fpfh_ransac.hpp"

#include <pcl/features/fpfh.h>
#include <pcl/features/normal_3d.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/registration/sample_consensus_prerejective.h>
#include <pcl/search/kdtree.h>

#include <cstdlib>
#include <stdexcept>

#include "forestslam/common/pcl_adapter.hpp"

namespace forestslam::registration {
namespace {

using CloudN = pcl::PointCloud<pcl::PointNormal>;
using Features = pcl::PointCloud<pcl::FPFHSignature33>;

void describe(const Points3 &points, const FpfhConfig &config, CloudN::Ptr &cloud,
              Features::Ptr &features) {
    auto xyz = detail::toPcl(points);
    auto normals = std::make_shared<pcl::PointCloud<pcl::Normal>>();
    pcl::NormalEstimation<pcl::PointXYZ, pcl::Normal> ne;
    ne.setInputCloud(xyz);
    ne.setSearchMethod(std::make_shared<pcl::search::KdTree<pcl::PointXYZ>>());
    ne.setRadiusSearch(config.normal_radius_m);
    ne.setViewPoint(0.f, 0.f, 0.f);  // sensor origin: consistent orientation
    ne.compute(*normals);
    cloud = std::make_shared<CloudN>();
    pcl::concatenateFields(*xyz, *normals, *cloud);
    features = std::make_shared<Features>();
    pcl::FPFHEstimation<pcl::PointNormal, pcl::PointNormal, pcl::FPFHSignature33> fe;
    fe.setInputCloud(cloud);
    fe.setInputNormals(cloud);
    fe.setSearchMethod(std::make_shared<pcl::search::KdTree<pcl::PointNormal>>());
    fe.setRadiusSearch(config.feature_radius_m);
    fe.compute(*features);
    // Points without a valid normal produce NaN features; keep only finite ones.
    CloudN::Ptr c2 = std::make_shared<CloudN>();
    Features::Ptr f2 = std::make_shared<Features>();
    for (size_t i = 0; i < cloud->size(); ++i) {
        bool ok = std::isfinite((*cloud)[i].normal_x);
        for (float v : (*features)[i].histogram) ok = ok && std::isfinite(v);
        if (!ok) continue;
        c2->push_back((*cloud)[i]);
        f2->push_back((*features)[i]);
    }
    cloud = c2;
    features = f2;
}

}  // namespace

Points3 voxelCentroids(const Eigen::Ref<const Points3> &points, double voxel_m) {
    const Points3 finite = finiteRows(points);
    if (finite.rows() == 0 || !(voxel_m > 0.0)) return finite;
    auto cloud = detail::toPcl(finite);
    pcl::PointCloud<pcl::PointXYZ> out;
    pcl::VoxelGrid<pcl::PointXYZ> vg;
    vg.setInputCloud(cloud);
    const float v = static_cast<float>(voxel_m);
    vg.setLeafSize(v, v, v);
    vg.filter(out);
    return detail::fromPcl(out);
}

RegistrationResult registerFpfh(const Eigen::Ref<const Points3> &source_in,
                                const Eigen::Ref<const Points3> &target_in, const Pose3 &T_init,
                                const FpfhConfig &config) {
    if (!T_init.matrix().allFinite())
        throw std::invalid_argument("registerFpfh: T_init is not finite");
    RegistrationResult result;
    result.T_target_source = T_init;
    result.covariance = Matrix6d::Identity() * kUnobservedVariance;
    const Points3 src = voxelCentroids(source_in, config.voxel_m);
    const Points3 tgt = voxelCentroids(target_in, config.voxel_m);
    if (src.rows() < 10 || tgt.rows() < 10) return result;

    CloudN::Ptr src_cloud, tgt_cloud;
    Features::Ptr src_feat, tgt_feat;
    describe(src, config, src_cloud, src_feat);
    describe(tgt, config, tgt_cloud, tgt_feat);
    Pose3 T0 = T_init;
    int ransac_inliers = 0;
    bool ransac_ok = false;
    if (src_cloud->size() >= 3 && tgt_cloud->size() >= 3) {
        std::srand(config.seed);  // PCL's sampler draws from rand()
        pcl::SampleConsensusPrerejective<pcl::PointNormal, pcl::PointNormal, pcl::FPFHSignature33>
            align;
        align.setInputSource(src_cloud);
        align.setSourceFeatures(src_feat);
        align.setInputTarget(tgt_cloud);
        align.setTargetFeatures(tgt_feat);
        align.setMaximumIterations(config.ransac_iterations);
        align.setNumberOfSamples(3);
        align.setCorrespondenceRandomness(config.correspondence_randomness);
        align.setSimilarityThreshold(static_cast<float>(config.similarity_threshold));
        align.setMaxCorrespondenceDistance(config.inlier_distance_m);
        align.setInlierFraction(static_cast<float>(config.inlier_fraction));
        CloudN aligned;
        align.align(aligned, T_init.matrix().cast<float>());
        if (align.hasConverged()) {
            T0.matrix() = align.getFinalTransformation().cast<double>();
            ransac_inliers = static_cast<int>(align.getInliers().size());
            ransac_ok = true;
        }
    }
    const PlaneTarget target(tgt);
    result = icpPointToPlane(target, src, T0, config.icp);
    result.degenerate = result.degenerate || !ransac_ok;
    result.inliers = ransac_inliers;
    return result;
}

}  // namespace forestslam::registration
