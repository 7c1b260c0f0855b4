// The CUDA backend against its oracle, the CPU backend (nvblox's pattern of
// a plain CPU integrator checking the CUDA one): the same frames integrated,
// de-integrated and re-integrated at corrected poses on both, then every
// voxel compared. Without a CUDA device each test is skipped with one line.
//
// Tolerance: none; every voxel (SDF sum, weight, r, g, b) must be identical.
// Why that is possible: the voxel maths (volume_kernels.hpp) uses only +, -,
// *, /, floorf, sqrtf and float<->int conversions, which IEEE 754 rounds
// correctly on the host (x86-64 SSE) and on the GPU (nvcc's defaults
// -prec-div=true, -prec-sqrt=true, -ftz=false), so the same operations in
// the same order give the same bits. What breaks that is contraction: by
// default nvcc fuses a*b+c into one FMA with one rounding instead of two.
// One ulp in u = fx*x/z + cx moves a voxel to the neighbouring pixel at a
// half-pixel boundary (another depth: an SDF error up to the truncation, not
// an ulp), one ulp in tsdf*1023 + 0.5 moves a rounded SDF step, and in the
// band walk one backend may allocate a block the other does not. Such
// differences are rare but unbounded, so a tolerance would have to let a
// fraction of voxels differ arbitrarily, which is also what a real bug looks
// like. So cuda/ is compiled with --fmad=false and rekon_volume with
// -ffp-contract=off, and the comparison is exact: the cost is one extra
// instruction per unfused pair in kernels bound by memory traffic.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>
#include <tuple>

#include <opencv2/core.hpp>

#include "analytic_scene.hpp"
#include "rekon/common/dataset.hpp"
#include "rekon/mapper/volume/tsdf_volume.hpp"
#include "test_support.hpp"
#include "volume_snapshot.hpp"

namespace {

using rekon::Pose;
using rekon::volume::BlockCoord;
using rekon::volume::TsdfVolume;
using rekon::volume::VolumeParams;
using rekon::volume::Voxel;

struct Frame {
  cv::Mat depth, color, weights;  // weights empty: every pixel weighs 1
  Pose pose;
};

using rekon::test::Snapshot;
using rekon::test::snapshot;

std::string describe(const Voxel& v) {
  using rekon::volume::voxelColorFixed;
  std::ostringstream text;
  text << "sdf_sum " << v.sdf_sum << " weight " << rekon::volume::voxelWeight(v) << " rgb " << voxelColorFixed(v, 0)
       << "/" << voxelColorFixed(v, 1) << "/" << voxelColorFixed(v, 2);
  return text.str();
}

// Fails the test unless both volumes hold the same blocks with identical voxels.
void expectIdentical(const TsdfVolume& cpu, const TsdfVolume& cuda, const std::string& after) {
  const Snapshot a = snapshot(cpu), b = snapshot(cuda);
  int64_t missing = 0, differing = 0, observed = 0;
  std::string first;
  for (const auto& [coord, va] : a) {
    const auto it = b.find(coord);
    if (it == b.end()) {
      ++missing;
      continue;
    }
    for (size_t i = 0; i < va.size(); ++i) {
      const Voxel &x = va[i], &y = it->second[i];
      observed += rekon::volume::voxelWeight(x) != 0u;
      if (x.sdf_sum == y.sdf_sum && x.bits[0] == y.bits[0] && x.bits[1] == y.bits[1]) continue;
      if (differing++ == 0) {
        std::ostringstream text;
        text << "block (" << std::get<0>(coord) << "," << std::get<1>(coord) << "," << std::get<2>(coord) << ") voxel "
             << i << ": cpu " << describe(x) << ", cuda " << describe(y);
        first = text.str();
      }
    }
  }
  EXPECT_GT(observed, 10000) << after << ": too little was integrated to prove anything";
  EXPECT_EQ(a.size(), b.size()) << after << ": blocks cpu " << a.size() << ", cuda " << b.size();
  EXPECT_EQ(missing, 0) << after << ": blocks of the CPU volume absent from the CUDA volume";
  EXPECT_EQ(differing, 0) << after << ": voxels differ; the first, " << first;
}

void expectIdenticalRaycasts(const TsdfVolume& cpu, const TsdfVolume& cuda, const rekon::Intrinsics& k,
                             const Pose& pose) {
  const rekon::volume::RaycastImages a = cpu.raycast(k, pose), b = cuda.raycast(k, pose);
  EXPECT_GT(cv::countNonZero(a.depth), k.width * k.height / 10) << "the ray cast must see a surface";
  EXPECT_EQ(cv::norm(a.depth, b.depth, cv::NORM_INF), 0.0) << "ray cast depth differs";
  EXPECT_EQ(cv::norm(a.normals, b.normals, cv::NORM_INF), 0.0) << "ray cast normals differ";
  EXPECT_EQ(cv::norm(a.color, b.color, cv::NORM_INF), 0.0) << "ray cast color differs";
}

// A pose correction as the pose graph makes them: 0.5 degrees and 1 cm.
Pose corrected(const Pose& pose, int i) {
  const Eigen::Vector3d axis = Eigen::Vector3d(1.0, 0.3 * (i % 3), -0.5).normalized();
  Pose delta = Pose::Identity();
  delta.linear() = Eigen::AngleAxisd(0.5 * M_PI / 180.0, axis).toRotationMatrix();
  delta.translation() = Eigen::Vector3d(0.01, -0.005, 0.004);
  return pose * delta;
}

class CudaOracle : public ::testing::Test {
 protected:
  void SetUp() override {
    const rekon::volume::CudaProbe probe = rekon::volume::probeCudaDevices();
    // A machine with a GPU whose driver fails is broken, not "without a GPU".
    if (probe.driver_error) FAIL() << "CUDA driver error: " << probe.detail;
    if (probe.devices == 0) GTEST_SKIP() << "no CUDA device: " << probe.detail;
  }

  // Integrates every frame, de-integrates the odd ones, re-integrates those
  // at corrected poses (the mapper's surface correction), comparing after each.
  void integrateDeintegrateReintegrate(VolumeParams params, std::vector<Frame> frames, const rekon::Intrinsics& k) {
    params.backend = "cpu";
    TsdfVolume cpu(params);
    params.backend = "cuda";
    TsdfVolume cuda(params);
    ASSERT_EQ(cuda.backendName(), "cuda");
    auto apply = [&](const Frame& f, bool integrate) {
      for (TsdfVolume* v : {&cpu, &cuda}) {
        v->streamAround(f.pose.translation());
        if (integrate) {
          v->integrate(f.depth, f.color, f.weights, k, f.pose);
        } else {
          v->deintegrate(f.depth, f.color, f.weights, k, f.pose);
        }
      }
    };
    for (const Frame& f : frames) apply(f, true);
    expectIdentical(cpu, cuda, "integration of " + std::to_string(frames.size()) + " frames");
    for (size_t i = 1; i < frames.size(); i += 2) apply(frames[i], false);
    expectIdentical(cpu, cuda, "de-integration of the odd frames");
    for (size_t i = 1; i < frames.size(); i += 2) {
      frames[i].pose = corrected(frames[i].pose, static_cast<int>(i));
      apply(frames[i], true);
    }
    expectIdentical(cpu, cuda, "re-integration of the odd frames at corrected poses");
    for (TsdfVolume* v : {&cpu, &cuda}) v->streamAround(frames.front().pose.translation());
    expectIdenticalRaycasts(cpu, cuda, k, frames.front().pose);
  }
};

TEST_F(CudaOracle, TheStartUpSelfCheckPassesAndAutoPicksCuda) {
  const auto cpu = rekon::volume::makeCpuBackend(0);
  const auto cuda = rekon::volume::makeBackend("cuda", 0);
  EXPECT_EQ(rekon::volume::compareBackendsOnSyntheticFrames(*cpu, *cuda), "");
  EXPECT_EQ(rekon::volume::makeBackend("auto", 0)->name(), "cuda");
}

TEST_F(CudaOracle, RealFramesGiveTheCpuBackendsVoxels) {
  REKON_REQUIRE_DATASET(dir, "7scenes_loop_1000");
  const rekon::TumDataset dataset(dir);
  ASSERT_TRUE(dataset.hasGroundTruth());
  const rekon::Intrinsics& k = dataset.intrinsics();
  // Every 10th of the first 400 frames (a sweep of the scene); the even ones
  // carry keyframe-fusion-like per-pixel weights 1/z^2, the odd ones none.
  std::vector<Frame> frames;
  for (size_t i = 0; i < 400 && i < dataset.size(); i += 10) {
    const int p = rekon::nearestInTime(dataset.groundTruth(), dataset.timestamp(i), 0.02);
    if (p < 0) continue;
    const rekon::RgbdFrame raw = dataset.load(i);
    Frame f{rekon::volume::depthToMetres(raw.depth, k.depth_scale), raw.color, cv::Mat(), dataset.groundTruth()[p].pose};
    if (frames.size() % 2 == 0) {
      f.weights = cv::Mat(f.depth.size(), CV_32FC1, cv::Scalar(0.f));
      for (int v = 0; v < f.depth.rows; ++v) {
        for (int u = 0; u < f.depth.cols; ++u) {
          const float z = f.depth.at<float>(v, u);
          if (z > 0.3f) f.weights.at<float>(v, u) = 1.f / (z * z);
        }
      }
    }
    frames.push_back(std::move(f));
  }
  ASSERT_GE(frames.size(), 30u);
  VolumeParams params;                  // the defaults: voxel 1 cm, truncation 4 cm, 4 m
  params.block_capacity = 1 << 12;      // small, so the pool grows during the run
  params.streaming_radius = 2.5;        // blocks stream out and back in as the camera moves
  integrateDeintegrateReintegrate(params, std::move(frames), k);
}

TEST_F(CudaOracle, SyntheticSphereFramesGiveTheCpuBackendsVoxels) {
  const rekon::test::SphereScene scene;
  const rekon::Intrinsics k = rekon::test::smallCamera(320, 240);
  std::vector<Frame> frames;
  for (int i = 0; i < 12; ++i) {
    Frame f;
    f.pose = rekon::test::orbitPose(scene, -60.0 + 10.0 * i);
    rekon::test::renderSphereScene(scene, k, f.pose, f.depth, f.color);
    if (i % 3 == 0) f.weights = cv::Mat(f.depth.size(), CV_32FC1, cv::Scalar(0.75f));
    frames.push_back(std::move(f));
  }
  VolumeParams params;
  params.voxel_size = 0.005;
  params.truncation = 0.02;
  params.block_capacity = 256;      // grows several times
  params.streaming_radius = 1.6;    // the far wall's blocks stream out and back in
  integrateDeintegrateReintegrate(params, std::move(frames), k);
}

}  // namespace
