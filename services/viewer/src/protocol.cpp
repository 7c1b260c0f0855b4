#include "rekon/viewer/protocol.hpp"

#include <fmt/format.h>

#include <charconv>
#include <cmath>
#include <cstring>

namespace rekon::viewer {
namespace {

static_assert(sizeof(float) == 4 && sizeof(double) == 8, "the protocol is IEEE-754");

size_t padded4(size_t n) { return (n + 3) & ~size_t{3}; }

template <class T>
void put(std::string& out, size_t at, const T& value) {
  std::memcpy(out.data() + at, &value, sizeof(T));
}

template <class T>
T get(std::string_view in, size_t at) {
  T value;
  std::memcpy(&value, in.data() + at, sizeof(T));
  return value;
}

// Bytes of a block message with n vertices and t triangles.
size_t messageBytes(size_t n, size_t t) { return kBlockHeaderBytes + 12 * n + padded4(3 * n) + 12 * t; }

}  // namespace

std::optional<std::string> parseClientReport(std::string_view text) {
  if (text.find(R"("type":"report")") == std::string_view::npos) return std::nullopt;
  std::string json = "{";
  for (const char* key : kReportKeys) {
    const std::string tag = fmt::format(R"("{}":)", key);
    const size_t at = text.find(tag);
    if (at == std::string_view::npos) continue;
    const char* first = text.data() + at + tag.size();
    double value = 0;
    const auto [end, ec] = std::from_chars(first, text.data() + text.size(), value);
    if (ec != std::errc{} || end == first || !std::isfinite(value)) continue;
    json += fmt::format(R"({}"{}":{})", json.size() > 1 ? "," : "", key, value);
  }
  return json + "}";
}

std::string encodeBlockMessage(const BlockMesh& b) {
  const size_t n = b.vertices.size(), t = b.triangles.size();
  std::string out(messageBytes(n, t), '\0');
  put(out, 0, kBlockMagic);
  put(out, 4, b.x);
  put(out, 8, b.y);
  put(out, 12, b.z);
  put(out, 16, static_cast<double>(b.version));
  put(out, 24, static_cast<uint32_t>(n));
  put(out, 28, static_cast<uint32_t>(t));
  put(out, 32, static_cast<uint8_t>(b.cause));
  size_t at = kBlockHeaderBytes;
  for (const Eigen::Vector3f& v : b.vertices) {
    std::memcpy(out.data() + at, v.data(), 12);
    at += 12;
  }
  if (b.colors.size() == n) {
    for (size_t i = 0; i < n; ++i) std::memcpy(out.data() + at + 3 * i, b.colors[i].data(), 3);
  }
  at += padded4(3 * n);
  for (const Eigen::Vector3i& tri : b.triangles) {
    for (int k = 0; k < 3; ++k) put(out, at + 4 * static_cast<size_t>(k), static_cast<uint32_t>(tri[k]));
    at += 12;
  }
  return out;
}

std::optional<BlockMesh> decodeBlockMessage(std::string_view in) {
  if (in.size() < kBlockHeaderBytes || get<uint32_t>(in, 0) != kBlockMagic) return std::nullopt;
  const size_t n = get<uint32_t>(in, 24), t = get<uint32_t>(in, 28);
  if (n > in.size() / 12 || t > in.size() / 12 || messageBytes(n, t) != in.size()) return std::nullopt;
  BlockMesh b;
  b.x = get<int32_t>(in, 4);
  b.y = get<int32_t>(in, 8);
  b.z = get<int32_t>(in, 12);
  b.version = static_cast<int64_t>(get<double>(in, 16));
  const uint8_t cause = get<uint8_t>(in, 32);
  if (cause > kMaxBlockCause) return std::nullopt;
  b.cause = static_cast<BlockCause>(cause);
  size_t at = kBlockHeaderBytes;
  b.vertices.resize(n);
  for (size_t i = 0; i < n; ++i, at += 12) std::memcpy(b.vertices[i].data(), in.data() + at, 12);
  b.colors.resize(n);
  for (size_t i = 0; i < n; ++i) std::memcpy(b.colors[i].data(), in.data() + at + 3 * i, 3);
  at += padded4(3 * n);
  b.triangles.resize(t);
  for (size_t i = 0; i < t; ++i, at += 12) {
    for (int k = 0; k < 3; ++k) {
      const uint32_t index = get<uint32_t>(in, at + 4 * static_cast<size_t>(k));
      if (index >= n) return std::nullopt;
      b.triangles[i][k] = static_cast<int>(index);
    }
  }
  return b;
}

std::string blockUpdateKey(const BlockKey& key) { return fmt::format("b {} {} {}", key.x, key.y, key.z); }

std::string plyBytes(const Mesh& mesh) {
  const bool colored = mesh.colors.size() == mesh.vertices.size() && !mesh.vertices.empty();
  std::string out = fmt::format("ply\nformat binary_little_endian 1.0\ncomment rekon\nelement vertex {}\n"
                                "property float x\nproperty float y\nproperty float z\n",
                                mesh.vertices.size());
  if (colored) out += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  out += fmt::format("element face {}\nproperty list uchar int vertex_indices\nend_header\n", mesh.triangles.size());
  out.reserve(out.size() + mesh.vertices.size() * 15 + mesh.triangles.size() * 13);
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    out.append(reinterpret_cast<const char*>(mesh.vertices[i].data()), 12);
    if (colored) out.append(reinterpret_cast<const char*>(mesh.colors[i].data()), 3);
  }
  for (const auto& tri : mesh.triangles) {
    out.push_back(3);
    out.append(reinterpret_cast<const char*>(tri.data()), 12);
  }
  return out;
}

}  // namespace rekon::viewer
