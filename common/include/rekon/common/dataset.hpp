#pragma once
// A sequence in TUM RGB-D layout: rgb.txt and depth.txt ("timestamp path"
// lines), optional groundtruth.txt, and camera.yaml with the intrinsics.
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "rekon/common/camera.hpp"
#include "rekon/common/pose.hpp"
#include "rekon/common/rgbd_frame.hpp"

namespace rekon {

struct DatasetOptions {
  // Largest rgb/depth timestamp difference accepted as one frame (TUM's associate.py default).
  static constexpr double kDefaultMaxTimeDifference = 0.02;
  double max_time_difference = kDefaultMaxTimeDifference;
  std::optional<Intrinsics> intrinsics_override;  // instead of camera.yaml
  int max_frames = 0;                             // 0 = all
};

class TumDataset {
 public:
  // Reads the index files and camera.yaml; throws rekon::Error naming the file
  // and the fix when something is missing, malformed or empty.
  explicit TumDataset(const std::string& dir, const DatasetOptions& options = {});

  const std::string& dir() const { return dir_; }
  const Intrinsics& intrinsics() const { return intrinsics_; }
  size_t size() const { return entries_.size(); }
  double timestamp(size_t i) const { return entries_.at(i).timestamp; }
  // Timestamp span of the sequence (last minus first), in seconds.
  double duration() const;

  // Checks that every image the index files list exists (a stat per file, no
  // reading); throws rekon::Error naming how many are missing and the first.
  void checkImagesExist() const;

  // Loads frame i from disk (checks decoding, bit depth and size).
  RgbdFrame load(size_t i) const;
  // The files of frame i as they are on disk (no decoding).
  EncodedFrame loadEncoded(size_t i) const;
  // Decodes what loadEncoded(i) returned, with the same checks as load(i).
  RgbdFrame decode(size_t i, const EncodedFrame& encoded) const;

  // Writes a dataset of the frames `keep` accepts into `out` (created): its
  // rgb.txt and depth.txt list those frames' images where they are (absolute
  // paths, each pair under its rgb timestamp); camera.yaml and groundtruth.txt
  // are copied. Returns how many frames it lists.
  size_t writeSubset(const std::string& out, const std::function<bool(size_t)>& keep) const;
  // Ground truth, when groundtruth.txt exists.
  bool hasGroundTruth() const { return !ground_truth_.empty(); }
  const Trajectory& groundTruth() const { return ground_truth_; }

 private:
  struct Entry {
    double timestamp;
    std::string rgb;
    std::string depth;
  };
  std::string dir_;
  Intrinsics intrinsics_;
  std::vector<Entry> entries_;
  Trajectory ground_truth_;
};

}  // namespace rekon
