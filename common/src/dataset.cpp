#include "rekon/common/dataset.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <sstream>
#include <tuple>

#include "rekon/common/error.hpp"
#include "rekon/common/image_io.hpp"

namespace rekon {
namespace fs = std::filesystem;
namespace {

struct IndexLine {
  double timestamp;
  std::string path;
};

std::vector<IndexLine> readIndex(const fs::path& file) {
  std::ifstream in(file);
  if (!in) throw Error(file.string() + ": missing; a TUM dataset needs rgb.txt and depth.txt ('timestamp path' lines)");
  std::vector<IndexLine> out;
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    const auto first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;
    std::istringstream ss(line);
    IndexLine e;
    if (!(ss >> e.timestamp >> e.path) || !std::isfinite(e.timestamp)) {
      throw Error(file.string() + ":" + std::to_string(line_no) + ": expected 'timestamp path'; fix the line");
    }
    out.push_back(e);
  }
  return out;
}

}  // namespace

TumDataset::TumDataset(const std::string& dir, const DatasetOptions& options) : dir_(dir) {
  const fs::path root(dir);
  if (!fs::is_directory(root)) throw Error(dir + ": dataset folder not found; pass --dataset with a TUM RGB-D folder");
  intrinsics_ = options.intrinsics_override ? *options.intrinsics_override : loadIntrinsics((root / "camera.yaml").string());
  intrinsics_.validate(dir);

  const auto rgb = readIndex(root / "rgb.txt");
  const auto depth = readIndex(root / "depth.txt");

  // TUM association: candidate pairs within the time limit, taken greedily by
  // smallest difference, each image used at most once.
  struct Pair {
    double diff;
    size_t r, d;
  };
  std::vector<Pair> pairs;
  std::vector<size_t> rgb_by_time(rgb.size());
  for (size_t r = 0; r < rgb.size(); ++r) rgb_by_time[r] = r;
  std::sort(rgb_by_time.begin(), rgb_by_time.end(),
            [&](size_t a, size_t b) { return rgb[a].timestamp < rgb[b].timestamp; });
  for (size_t d = 0; d < depth.size(); ++d) {
    const double lo = depth[d].timestamp - options.max_time_difference;
    auto it = std::lower_bound(rgb_by_time.begin(), rgb_by_time.end(), lo,
                               [&](size_t r, double t) { return rgb[r].timestamp < t; });
    for (; it != rgb_by_time.end(); ++it) {
      const double diff = rgb[*it].timestamp - depth[d].timestamp;
      if (diff > options.max_time_difference) break;
      pairs.push_back({std::abs(diff), *it, d});
    }
  }
  std::sort(pairs.begin(), pairs.end(), [](const Pair& a, const Pair& b) { return a.diff < b.diff; });
  std::vector<bool> used_rgb(rgb.size()), used_depth(depth.size());
  for (const auto& p : pairs) {
    if (used_rgb[p.r] || used_depth[p.d]) continue;
    used_rgb[p.r] = used_depth[p.d] = true;
    entries_.push_back({rgb[p.r].timestamp, rgb[p.r].path, depth[p.d].path});
  }
  std::sort(entries_.begin(), entries_.end(), [](const Entry& a, const Entry& b) { return a.timestamp < b.timestamp; });
  if (entries_.empty()) {
    throw Error(dir + ": no rgb/depth pairs within " + std::to_string(options.max_time_difference) +
                " s of each other; check rgb.txt and depth.txt");
  }
  if (options.max_frames > 0 && entries_.size() > static_cast<size_t>(options.max_frames)) entries_.resize(options.max_frames);

  const fs::path gt = root / "groundtruth.txt";
  if (fs::exists(gt)) ground_truth_ = readTumTrajectory(gt.string());
}

double TumDataset::duration() const { return entries_.back().timestamp - entries_.front().timestamp; }

void TumDataset::checkImagesExist() const {
  const fs::path root(dir_);
  for (const auto& [kind, member, index] : {std::tuple{"depth", &Entry::depth, "depth.txt"}, std::tuple{"color", &Entry::rgb, "rgb.txt"}}) {
    size_t missing = 0;
    std::string first;
    for (const Entry& e : entries_) {
      if (fs::exists(root / (e.*member))) continue;
      if (missing++ == 0) first = (root / (e.*member)).string();
    }
    if (missing > 0) {
      throw Error(dir_ + ": " + std::to_string(missing) + " of the " + std::to_string(entries_.size()) + " " + kind +
                  " images " + index + " lists are missing (the first: " + first + "); copy them in, or list only those present");
    }
  }
}

size_t TumDataset::writeSubset(const std::string& out, const std::function<bool(size_t)>& keep) const {
  const fs::path root = fs::absolute(dir_), to(out);
  std::error_code ec;
  fs::create_directories(to, ec);
  if (ec) throw Error(out + ": cannot create the folder (" + ec.message() + "); choose another --out");
  std::ofstream rgb(to / "rgb.txt"), depth(to / "depth.txt");
  const std::string header = "# the frames of " + root.string() + " kept for a comparison (TumDataset::writeSubset)\n";
  rgb << header << std::fixed << std::setprecision(9);
  depth << header << std::fixed << std::setprecision(9);
  size_t kept = 0;
  for (size_t i = 0; i < entries_.size(); ++i) {
    if (!keep(i)) continue;
    const Entry& e = entries_[i];
    rgb << e.timestamp << " " << (root / e.rgb).string() << "\n";
    depth << e.timestamp << " " << (root / e.depth).string() << "\n";
    ++kept;
  }
  if (!rgb.flush() || !depth.flush()) throw Error(out + ": cannot write rgb.txt and depth.txt there; check the disk");
  for (const char* name : {"camera.yaml", "groundtruth.txt"}) {
    if (!fs::exists(root / name)) continue;
    fs::copy_file(root / name, to / name, fs::copy_options::overwrite_existing, ec);
    if (ec) throw Error((to / name).string() + ": cannot copy " + name + " there (" + ec.message() + "); check the disk");
  }
  return kept;
}

RgbdFrame TumDataset::load(size_t i) const { return decode(i, loadEncoded(i)); }

EncodedFrame TumDataset::loadEncoded(size_t i) const {
  const Entry& e = entries_.at(i);
  const fs::path root(dir_);
  EncodedFrame f;
  f.depth_png = readFileBytes((root / e.depth).string());
  f.color = readFileBytes((root / e.rgb).string());
  const std::string ext = fs::path(e.rgb).extension().string();
  f.color_format = (ext == ".jpg" || ext == ".jpeg" || ext == ".JPG") ? "jpeg" : "png";
  return f;
}

RgbdFrame TumDataset::decode(size_t i, const EncodedFrame& encoded) const {
  const Entry& e = entries_.at(i);
  const fs::path root(dir_);
  RgbdFrame f;
  f.id = static_cast<int64_t>(i);
  f.timestamp = e.timestamp;
  f.depth = decodeDepthPng(encoded.depth_png.data(), encoded.depth_png.size(), intrinsics_.width, intrinsics_.height,
                           (root / e.depth).string());
  f.color = decodeColor(encoded.color.data(), encoded.color.size(), intrinsics_.width, intrinsics_.height,
                        (root / e.rgb).string());
  return f;
}

}  // namespace rekon
