// `rekon keyframes`: reads the mapper's shared-memory keyframe store from another process.
#include <spdlog/spdlog.h>

#include <cstdio>
#include <filesystem>
#include <fstream>

#include "commands.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/image_io.hpp"
#include "rekon/mapper/store/keyframe_store.hpp"

namespace rekon {
namespace {

using store::KeyframeInfo;
using store::KeyframeStore;
using store::StoreOptions;
using store::StoreUsage;

void printList(const KeyframeStore& store) {
  const auto infos = store.list();
  const StoreUsage u = store.usage();
  std::printf("store %s: %zu keyframes, %zu in shared memory (%.1f of %.1f MiB used), %zu spilled (%.1f MiB in %s)\n",
              store.segment().c_str(), infos.size(), u.resident, static_cast<double>(u.shm_used_bytes) / (1 << 20),
              static_cast<double>(u.shm_total_bytes) / (1 << 20), u.spilled,
              static_cast<double>(u.spilled_bytes) / (1 << 20), u.spill_dir.empty() ? "(spilling off)" : u.spill_dir.c_str());
  std::printf("%6s %8s %8s %8s %6s %12s %5s %s\n", "id", "anchor", "first", "last", "frames", "timestamp", "where",
              "integrated at (tx ty tz)");
  for (const KeyframeInfo& i : infos) {
    const Eigen::Vector3d t = i.integrated_pose.translation();
    std::printf("%6ld %8ld %8ld %8ld %6d %12.4f %5s ", static_cast<long>(i.id), static_cast<long>(i.anchor_keyframe_id),
                static_cast<long>(i.first_frame_id), static_cast<long>(i.last_frame_id), i.frames, i.timestamp,
                i.spilled ? "disk" : "shm");
    if (i.integrated) std::printf("%.4f %.4f %.4f\n", t.x(), t.y(), t.z());
    else std::printf("not yet\n");
  }
}

// depth as 16-bit PNG at the camera's depth_scale, weights as 16-bit PNG in
// 1/1000 units (saturated), color as PNG; poses as TUM trajectories.
void exportTo(const KeyframeStore& store, const std::string& dir) {
  createOutputFolder(dir);
  const Intrinsics k = store.intrinsics();
  const auto infos = store.list();
  Trajectory integrated;
  std::ofstream meta(std::filesystem::path(dir) / "keyframes.txt");
  meta << "# id anchor_keyframe_id first_frame last_frame frames timestamp integrated spilled\n";
  for (size_t i = 0; i < infos.size(); ++i) {
    const fusion::FusedKeyframe kf = store.load(i);
    char name[64];
    std::snprintf(name, sizeof(name), "kf_%06ld", static_cast<long>(kf.id));
    cv::Mat depth16, weight16;
    kf.depth.convertTo(depth16, CV_16U, k.depth_scale);
    kf.weight.convertTo(weight16, CV_16U, 1000.0);
    writeImage((std::filesystem::path(dir) / (std::string(name) + "_depth.png")).string(), depth16);
    writeImage((std::filesystem::path(dir) / (std::string(name) + "_weight.png")).string(), weight16);
    writeImage((std::filesystem::path(dir) / (std::string(name) + "_color.png")).string(), kf.color);
    meta << kf.id << ' ' << kf.anchor_keyframe_id << ' ' << kf.first_frame_id << ' ' << kf.last_frame_id << ' '
         << kf.frames << ' ' << std::fixed << kf.timestamp << ' ' << (infos[i].integrated ? 1 : 0) << ' '
         << (infos[i].spilled ? 1 : 0) << '\n';
    if (infos[i].integrated) integrated.push_back({kf.timestamp, infos[i].integrated_pose});
  }
  writeTumTrajectory(integrated, (std::filesystem::path(dir) / "integrated_poses.txt").string());
  saveIntrinsics(k, (std::filesystem::path(dir) / "camera.yaml").string());
  std::printf("exported %zu keyframes to %s\n", infos.size(), dir.c_str());
}

}  // namespace

int keyframesCommand(int argc, char** argv) {
  ArgParser args(argv[0], "Lists or exports the KF keyframes in the mapper's shared-memory keyframe store "
                          "(spilled ones included: read back from their spill files).");
  args.flag("list", "print one line per keyframe")
      .option("export", "write depth, weight and color PNGs, keyframes.txt and integrated_poses.txt into DIR")
      .flag("remove", "delete the store and its spill files (e.g. after a crashed mapper)")
      .option("segment", "name of the shared-memory segment (mapper.store_segment)", StoreOptions{}.segment);
  if (!args.parse(argc, argv)) return 0;
  const std::string segment = args.get("segment");
  if (args.flagSet("remove")) {
    const bool removed = KeyframeStore::remove(segment);
    std::printf("%s %s\n", removed ? "removed" : "no store named", segment.c_str());
    return 0;
  }
  if (!args.flagSet("list") && !args.has("export"))
    throw Error("rekon keyframes: give --list, --export DIR or --remove");
  const auto store = KeyframeStore::openExisting(segment);
  if (args.flagSet("list")) printList(*store);
  if (args.has("export")) exportTo(*store, args.get("export"));
  return 0;
}

}  // namespace rekon
