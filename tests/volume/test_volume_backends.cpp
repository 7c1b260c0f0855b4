// Choosing a backend and the start-up self-check that decides whether the
// CUDA backend may be trusted. The check itself is exercised here on the CPU:
// against a second CPU backend it must pass, against a backend with a
// planted fault it must name the fault.
#include <gtest/gtest.h>

#include <algorithm>

#include "rekon/common/error.hpp"
#include "rekon/mapper/volume/volume_backend.hpp"

namespace {

using namespace rekon::volume;

enum class Fault { None, DropsABandBlock, LosesColor, SdfOffByOneStep, WrongEmptyFlag };

// The CPU backend with one planted fault, of the kinds a GPU port can have.
class FaultyBackend final : public VolumeBackend {
 public:
  explicit FaultyBackend(Fault fault) : inner_(makeCpuBackend(1)), fault_(fault) {}
  std::string name() const override { return "faulty"; }
  void resizePool(int32_t blocks) override { inner_->resizePool(blocks); }
  void setFrame(const FrameImages& frame) override {
    FrameImages f = frame;
    if (fault_ == Fault::LosesColor) f.bgr = nullptr;
    inner_->setFrame(f);
  }
  void collectBandBlocks(const CameraView& cam, const IntegrationSettings& s, int stride,
                         std::vector<BlockCoord>& out) override {
    inner_->collectBandBlocks(cam, s, stride, out);
    if (fault_ == Fault::DropsABandBlock && !out.empty()) {
      // A truncated candidate buffer: one block (every copy of it) goes missing.
      const BlockCoord lost = out.back();
      out.erase(std::remove(out.begin(), out.end(), lost), out.end());
    }
  }
  FrameUpdateReport updateBlocks(const CameraView& cam, const IntegrationSettings& s,
                                 const std::vector<BlockRef>& blocks, int sign, std::vector<uint8_t>& empty) override {
    const FrameUpdateReport r = inner_->updateBlocks(cam, s, blocks, sign, empty);
    if (fault_ == Fault::WrongEmptyFlag && !empty.empty()) empty.back() ^= 1;
    return r;
  }
  void readBlocks(const std::vector<int32_t>& slots, Voxel* out) const override {
    inner_->readBlocks(slots, out);
    if (fault_ != Fault::SdfOffByOneStep) return;
    // What an FMA-contracted rounding does: one observed voxel one SDF step off.
    for (size_t i = 0; i < slots.size() * kBlockVoxels; ++i) {
      if (voxelWeight(out[i]) != 0u) {
        out[i].sdf_sum += 1;
        return;
      }
    }
  }
  void writeBlocks(const std::vector<int32_t>& slots, const Voxel* in) override { inner_->writeBlocks(slots, in); }
  const Voxel* hostPool() const override { return nullptr; }
  void raycast(const std::vector<HashEntry>& table, uint64_t version, const CameraView& cam,
               const TileDepthRanges& ranges, int tiles, float voxel_size, float truncation, float max_depth,
               RaycastPixel* out) override {
    inner_->raycast(table, version, cam, ranges, tiles, voxel_size, truncation, max_depth, out);
  }

 private:
  std::unique_ptr<VolumeBackend> inner_;
  Fault fault_;
};

std::string check(Fault fault) {
  const auto reference = makeCpuBackend(0);
  FaultyBackend candidate(fault);
  return compareBackendsOnSyntheticFrames(*reference, candidate);
}

TEST(BackendSelfCheck, TwoCpuBackendsAgree) { EXPECT_EQ(check(Fault::None), ""); }

TEST(BackendSelfCheck, AMissingBandBlockIsNamed) {
  const std::string why = check(Fault::DropsABandBlock);
  EXPECT_NE(why.find("band blocks of frame A differ"), std::string::npos) << why;
}

TEST(BackendSelfCheck, LostColorIsFoundInTheVoxels) {
  const std::string why = check(Fault::LosesColor);
  EXPECT_NE(why.find("after integrating frame A"), std::string::npos) << why;
  EXPECT_NE(why.find("voxels differ"), std::string::npos) << why;
}

TEST(BackendSelfCheck, OneSdfStepOnOneVoxelIsFound) {
  const std::string why = check(Fault::SdfOffByOneStep);
  EXPECT_NE(why.find(" 1 of "), std::string::npos) << why;  // exactly one voxel differs
  EXPECT_NE(why.find("voxels differ"), std::string::npos) << why;
}

TEST(BackendSelfCheck, AWrongEmptyBlockFlagIsFound) {
  const std::string why = check(Fault::WrongEmptyFlag);
  EXPECT_NE(why.find("empty-block flags differ for 1 of"), std::string::npos) << why;
}

TEST(BackendSelfCheck, ItsMessageIsOneLine) {
  const std::string why = check(Fault::LosesColor);
  ASSERT_FALSE(why.empty());
  EXPECT_EQ(why.find('\n'), std::string::npos) << why;
}

// The remaining tests describe a machine without a usable CUDA device (every
// machine of this project's CI); with one, test_volume_cuda_oracle covers the choice.
class WithoutCudaDevice : public ::testing::Test {
 protected:
  void SetUp() override {
    probe_ = probeCudaDevices();
    if (probe_.devices > 0) GTEST_SKIP() << "a CUDA device is present: see test_volume_cuda_oracle";
  }
  CudaProbe probe_;
};

TEST_F(WithoutCudaDevice, TheProbeSaysWhy) { EXPECT_FALSE(probe_.detail.empty()); }

TEST_F(WithoutCudaDevice, AutoUsesTheCpuBackend) { EXPECT_EQ(makeBackend("auto", 1)->name(), "cpu"); }

TEST_F(WithoutCudaDevice, AnExplicitCudaBackendIsOneLineNamingTheFix) {
  try {
    makeBackend("cuda", 1);
    FAIL() << "volume.backend cuda without a device must throw";
  } catch (const rekon::Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("cuda"), std::string::npos) << what;
    EXPECT_NE(what.find("auto or cpu"), std::string::npos) << what;
    EXPECT_EQ(what.find('\n'), std::string::npos) << what;
  }
}

TEST(BackendSelection, AnUnknownBackendIsRejected) { EXPECT_THROW(makeBackend("opencl", 1), rekon::Error); }

TEST(BackendSelection, CpuIsAlwaysAvailable) {
  const std::vector<std::string> names = availableBackends();
  ASSERT_FALSE(names.empty());
  EXPECT_EQ(names.front(), "cpu");
}

}  // namespace
