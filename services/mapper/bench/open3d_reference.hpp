#pragma once
// Open3D's VoxelBlockGrid on the same frames and settings, for a side-by-side
// speed comparison (built only when libopen3d-dev is installed).
#include <opencv2/core/mat.hpp>

#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/common/pose.hpp"

struct Open3dResult {
  double integrate_ms_per_frame = 0.0;
  double integrate_cpu_ms_per_frame = 0.0;  // all threads (OpenMP spinning included)
  double mesh_s = 0.0;
  long long blocks = 0;
  size_t mesh_vertices = 0;
};

// depth_raw: CV_16UC1 in k.depth_scale units; color: CV_8UC3 BGR. float_voxels:
// tsdf/weight/color all float32 (Open3D's accurate mode), else its fast
// SLAM layout (tsdf float32, weight and color uint16).
Open3dResult runOpen3dReference(const std::vector<cv::Mat>& depth_raw, const std::vector<cv::Mat>& color,
                                const std::vector<rekon::Pose>& poses, const rekon::Intrinsics& k, double voxel_size,
                                double truncation, double max_depth, bool float_voxels);
