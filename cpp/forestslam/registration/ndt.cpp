#include "forestslam/registration/ndt.hpp"

#include <pcl/registration/ndt.h>

// KdTreeFLANN's methods compiled here instead of taken from PCL's shared library: FLANN's
// radius search opens an OpenMP parallel region per query (num_threads(1) by default), and the
// NDT asks one per source point per derivative evaluation (~60 % of its time went to libgomp
// and futex calls). Without -fopenmp the pragma is ignored: the same serial search, the same
// neighbours in the same order, the same results. The core's other KdTreeFLANN<PointXYZ> users
// link to these definitions too.
#include <pcl/kdtree/impl/kdtree_flann.hpp>
#include <stdexcept>

#include "forestslam/common/pcl_adapter.hpp"
#include "forestslam/features/voxel_grid.hpp"

namespace forestslam::registration {

namespace {

Points3 prepare(const Eigen::Ref<const Points3> &points, const NdtConfig &config) {
    Points3 sampled = features::voxelDownsample(points, config.voxel_m);
    std::vector<int> keep;
    const double r2 = config.max_range_m * config.max_range_m;
    for (Eigen::Index i = 0; i < sampled.rows(); ++i) {
        if (config.max_range_m <= 0 || sampled.row(i).squaredNorm() <= r2) {
            keep.push_back(static_cast<int>(i));
        }
    }
    return selectRows(sampled, keep);
}

}  // namespace

NdtResult registerNdt(const Eigen::Ref<const Points3> &target,
                      const Eigen::Ref<const Points3> &source, const Pose3 &T_initial,
                      const NdtConfig &config) {
    if (!T_initial.matrix().allFinite())
        throw std::invalid_argument("registerNdt: T_initial is not finite");
    NdtResult result;
    result.T_target_source = T_initial;
    const Points3 tgt = prepare(target, config);
    const Points3 src = prepare(source, config);
    if (tgt.rows() < config.min_points || src.rows() < config.min_points) return result;

    pcl::NormalDistributionsTransform<pcl::PointXYZ, pcl::PointXYZ> ndt;
    ndt.setResolution(static_cast<float>(config.resolution_m));
    ndt.setStepSize(config.step_size_m);
    ndt.setTransformationEpsilon(config.epsilon);
    ndt.setMaximumIterations(config.max_iterations);
    ndt.setInputTarget(detail::toPcl(tgt));
    ndt.setInputSource(detail::toPcl(src));
    pcl::PointCloud<pcl::PointXYZ> aligned;
    ndt.align(aligned, T_initial.matrix().cast<float>());
    const Eigen::Matrix4d T = ndt.getFinalTransformation().cast<double>();
    result.iterations = ndt.getFinalNumIteration();
    if (ndt.hasConverged() && T.allFinite()) {
        result.T_target_source = Pose3(T);
        result.converged = true;
        result.fitness = ndt.getFitnessScore();
    }
    return result;
}

}  // namespace forestslam::registration
