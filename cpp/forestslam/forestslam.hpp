// forestslam C++ core, everything at once: #include "forestslam/forestslam.hpp" and link
// forestslam::forestslam (find_package(forestslam)).
#pragma once

#include "forestslam/common/circle_fit.hpp"
#include "forestslam/common/types.hpp"
#include "forestslam/features/dog_keypoints.hpp"
#include "forestslam/features/virtual_features.hpp"
#include "forestslam/features/voxel_grid.hpp"
#include "forestslam/localization/global_localizer.hpp"
#include "forestslam/odometry/motion_model.hpp"
#include "forestslam/odometry/sensor_profile.hpp"
#include "forestslam/odometry/tree_odometry.hpp"
#include "forestslam/perception/detector.hpp"
#include "forestslam/registration/deskew.hpp"
#include "forestslam/registration/fpfh_ransac.hpp"
#include "forestslam/registration/ndt.hpp"
#include "forestslam/registration/point_to_plane_icp.hpp"
#include "forestslam/registration/shape_registration.hpp"
#include "forestslam/registration/stem_centre_lm.hpp"
#include "forestslam/registration/tree_correspondences.hpp"
#include "forestslam/sim/scan_synthesis.hpp"
