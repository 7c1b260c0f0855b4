#pragma once
// The viewer's WebSocket protocol (services/viewer/web/app.js decodes it).
//
// Binary message: one voxel block's surface (RKB2), little-endian, so that the page
// wraps typed arrays around it without copying:
//   offset 0   uint32  magic 0x31424B52 ("RKB1")
//          4   int32   bx, by, bz (block coordinates)
//          16  float64 version (a mapper's: wall-clock microseconds of the change)
//          24  uint32  vertices n, triangles t (both 0: the block was removed)
//          32  uint8   cause (0 new data, 1 a correction, 2 the final pass:
//                      rekon::BlockCause), zero padding to 36 bytes
//          36  float32 positions[3n] (world, metres)
//              uint8   colors[3n] (RGB), zero padding to a multiple of 4 bytes
//              uint32  indices[3t] (into this block's vertices)
// Text messages: JSON objects with a "type": "camera" (newest pose),
// "trajectory" (every camera position), "keyframes", "edges" (loop closures
// between keyframe ids), "status" (every service's heartbeat and stats),
// "counts" (the server's block, vertex and triangle totals), "live" (the
// state sent on connect is complete: later blocks are fresh changes).
// The page sends one text message, {"type":"report", ...} once a second: its
// own counts and the latency from a block's change in the mapper to the first
// frame drawn with it: of every version, of full meshes (latency_full_*), and
// of a block's first appearance (latency_new_*) (/state.json lists every
// client's newest report).
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "rekon/viewer/viewer_state.hpp"

namespace rekon::viewer {

inline constexpr uint32_t kBlockMagic = 0x32424B52;  // "RKB2": with the cause
inline constexpr size_t kBlockHeaderBytes = 36;

std::string encodeBlockMessage(const BlockMesh& block);
// nullopt for anything that is not a well-formed block message (sizes, magic, index range).
std::optional<BlockMesh> decodeBlockMessage(std::string_view bytes);

// The keys a page's report may carry (numbers only; anything else is ignored).
inline constexpr std::array<const char*, 20> kReportKeys = {
    "blocks",          "vertices",       "triangles",      "updates",           "corrections",
    "final_pass",      "coarse",         "messages",       "latency_samples",   "latency_ms_p50",
    "latency_ms_p95",  "latency_full_samples", "latency_full_ms_p50", "latency_full_ms_p95", "latency_new_samples",
    "latency_new_ms_p50", "latency_new_ms_p95", "position_sum", "handle_ms",   "draw_ms"};
// A page's report as a JSON object of the kReportKeys it has, with finite
// numbers only; nullopt when `text` is not a report.
std::optional<std::string> parseClientReport(std::string_view text);

// The Update key of a block ("b X Y Z").
std::string blockUpdateKey(const BlockKey& key);

// A mesh as binary little-endian PLY bytes, exactly what rekon::writePly writes to a file.
std::string plyBytes(const Mesh& mesh);

}  // namespace rekon::viewer
