// fuzz_seeds CORPUS_DIR: writes one valid input per message type and image
// kind into CORPUS_DIR/<fuzzer>/, so the fuzzers start past the fingerprint
// check and the image headers instead of having to guess them.
#include <filesystem>
#include <fstream>
#include <iostream>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "rekon/common/bus.hpp"
#include "rekon/common/camera.hpp"
#include "rekon/common/image_io.hpp"
#include "rekon/common/mesh_blocks.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/common/pose.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/end_of_stream_t.hpp"
#include "rekon_msgs/external_constraint_t.hpp"
#include "rekon_msgs/frame_ack_t.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/mesh_blocks_t.hpp"
#include "rekon_msgs/mesh_request_t.hpp"
#include "rekon_msgs/replay_end_t.hpp"
#include "rekon_msgs/replay_request_t.hpp"
#include "rekon_msgs/resume_point_t.hpp"
#include "rekon_msgs/service_stats_t.hpp"
#include "rekon_msgs/shutdown_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace fs = std::filesystem;

namespace {

// The fuzzers' image size (fuzz_images.cpp, fuzz_messages.cpp's frame sizes).
constexpr int kWidth = 64, kHeight = 48;

void write(const fs::path& dir, const std::string& name, uint8_t selector, const std::vector<uint8_t>& bytes) {
  fs::create_directories(dir);
  std::ofstream out(dir / name, std::ios::binary);
  out.put(static_cast<char>(selector));
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

// fuzz_messages reads the first byte as the message kind (its switch order).
template <class Msg>
void writeMessage(const fs::path& dir, const std::string& name, uint8_t kind, Msg msg) {
  msg.schema_version = rekon::kSchemaVersion;
  std::vector<uint8_t> buf(static_cast<size_t>(msg.getEncodedSize()));
  msg.encode(buf.data(), 0, static_cast<int>(buf.size()));
  write(dir, name, kind, buf);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::cerr << "usage: fuzz_seeds CORPUS_DIR\n";
    return 2;
  }
  const fs::path root(argv[1]);
  cv::Mat depth(kHeight, kWidth, CV_16UC1), color(kHeight, kWidth, CV_8UC3);
  cv::randu(depth, 500, 4000);
  cv::randu(color, 0, 255);
  const auto png_depth = rekon::encodePng(depth), png_color = rekon::encodePng(color);
  const auto jpeg_color = rekon::encodeJpeg(color);

  const fs::path images = root / "fuzz_images";
  write(images, "seed_depth.png", 1, png_depth);  // odd first byte: depth
  write(images, "seed_color.png", 0, png_color);
  write(images, "seed_color.jpg", 0, jpeg_color);

  const fs::path messages = root / "fuzz_messages";
  rekon::Intrinsics k;
  k.width = kWidth;
  k.height = kHeight;
  k.fx = k.fy = 50;
  k.cx = 31.5;
  k.cy = 23.5;
  for (const auto& [name, format, bytes] : {std::tuple{"seed_frame_jpeg", "jpeg", jpeg_color},
                                            std::tuple{"seed_frame_png", "png", png_color}}) {
    rekon_msgs::frame_t f{};
    f.frame_id = 3;
    f.timestamp = 0.1;
    rekon::setIntrinsics(k, &f);
    f.shm_slot = -1;
    f.depth_png = png_depth;
    f.depth_png_size = static_cast<int32_t>(f.depth_png.size());
    f.color_format = format;
    f.color = bytes;
    f.color_size = static_cast<int32_t>(f.color.size());
    writeMessage(messages, name, 0, f);
  }
  const auto pose = rekon::toMsg(rekon::poseFromQuatTrans(Eigen::Quaterniond(0.96, 0.0, 0.28, 0.0).normalized(),
                                                          Eigen::Vector3d(0.1, -0.2, 0.3)));
  rekon_msgs::graph_update_t g{};
  g.version = 2;
  g.num_keyframes = 3;
  g.keyframe_ids = {0, 4, 9};
  g.poses = {pose, pose, pose};
  writeMessage(messages, "seed_graph_update", 1, g);
  rekon_msgs::constraint_t c{};
  c.kind = rekon_msgs::constraint_t::KIND_LOOP;
  c.from_id = 9;
  c.to_id = 0;
  c.relative = pose;
  rekon::toArray(Eigen::Matrix<double, 6, 6>::Identity() * 1e4, c.information);
  writeMessage(messages, "seed_constraint", 2, c);
  rekon_msgs::tracked_frame_t t{};
  t.frame_id = 5;
  t.timestamp = 0.2;
  t.keyframe_id = 4;
  t.pose_in_keyframe = pose;
  rekon::toArray(Eigen::Matrix<double, 6, 6>::Identity() * 1e-4, t.covariance);
  writeMessage(messages, "seed_tracked_frame", 3, t);
  rekon_msgs::keyframe_t kf{};
  kf.keyframe_id = 4;
  kf.frame_id = 4;
  kf.timestamp = 0.15;
  kf.pose_world = pose;
  writeMessage(messages, "seed_keyframe", 4, kf);
  rekon_msgs::heartbeat_t hb{};
  hb.service = "tracker";
  hb.pid = 1234;
  hb.host = "host";
  hb.state = "playing";
  writeMessage(messages, "seed_heartbeat", 5, hb);
  rekon_msgs::frame_ack_t ack{};
  ack.service = "mapper";
  ack.frame_id = 7;
  writeMessage(messages, "seed_frame_ack", 6, ack);
  rekon_msgs::end_of_stream_t eos{};
  eos.last_frame_id = 59;
  eos.frames = 60;
  eos.duration_s = 2.0;
  writeMessage(messages, "seed_end_of_stream", 7, eos);
  rekon_msgs::service_stats_t stats{};
  stats.service = "mapper";
  stats.json = "{\"frames\": 60}";
  writeMessage(messages, "seed_service_stats", 8, stats);
  rekon_msgs::shutdown_t shutdown{};
  shutdown.reason = "operator";
  writeMessage(messages, "seed_shutdown", 9, shutdown);
  rekon_msgs::done_t done{};
  done.service = "tracker";
  done.pid = 4244;
  done.last_frame_id = 59;
  writeMessage(messages, "seed_done", 10, done);
  rekon_msgs::resume_point_t resume{};
  resume.service = "mapper";
  resume.pid = 4242;
  resume.first_missing_frame = 40;
  writeMessage(messages, "seed_resume_point", 11, resume);
  rekon_msgs::replay_request_t request{};
  request.service = "optimiser";
  request.pid = 4243;
  request.request_id = 1;
  writeMessage(messages, "seed_replay_request", 12, request);
  rekon_msgs::replay_end_t replay_end{};
  replay_end.service = "optimiser";
  replay_end.pid = 4243;
  replay_end.request_id = 1;
  replay_end.keyframes = 3;
  replay_end.graph_version = -1;
  writeMessage(messages, "seed_replay_end", 13, replay_end);
  rekon::BlockMesh block;  // one triangle in block (1, -2, 3)
  block.x = 1;
  block.y = -2;
  block.z = 3;
  block.version = 4;
  block.vertices = {{0.085f, -0.155f, 0.245f}, {0.09f, -0.15f, 0.245f}, {0.085f, -0.15f, 0.25f}};
  block.colors = {{{200, 10, 10}}, {{10, 200, 10}}, {{10, 10, 200}}};
  block.triangles = {{0, 1, 2}};
  rekon::MeshBlocksParams mesh_params;
  writeMessage(messages, "seed_mesh_blocks", 14, rekon::encodeMeshBlocks({block}, mesh_params, 1, false).front());
  rekon_msgs::mesh_request_t mesh_request{};
  mesh_request.requester = "viewer";
  writeMessage(messages, "seed_mesh_request", 15, mesh_request);
  rekon_msgs::external_constraint_t prior{};
  prior.source = "operator";
  prior.sequence = 1;
  prior.kind = rekon_msgs::external_constraint_t::KIND_PRIOR;
  prior.to_id = 3;
  prior.pose.q[3] = 1.0;
  for (int i = 0; i < 6; ++i) prior.information[i * 7] = 1e4;
  writeMessage(messages, "seed_external_constraint", 16, prior);
  std::cout << "seeds in " << root.string() << "\n";
  return 0;
}
