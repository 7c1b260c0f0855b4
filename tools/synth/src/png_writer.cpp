#include "png_writer.hpp"

#include <zlib.h>

#include <cstring>

#include "rekon/common/error.hpp"

namespace rekon::synth {
namespace {

constexpr uint8_t kFilterUp = 2;

void put32(std::vector<uint8_t>& out, uint32_t v) {
  for (int shift = 24; shift >= 0; shift -= 8) out.push_back(static_cast<uint8_t>(v >> shift));
}

void chunk(std::vector<uint8_t>& out, const char* type, const uint8_t* data, size_t size) {
  put32(out, static_cast<uint32_t>(size));
  const size_t start = out.size();
  out.insert(out.end(), type, type + 4);
  if (size > 0) out.insert(out.end(), data, data + size);
  put32(out, static_cast<uint32_t>(crc32(0, out.data() + start, static_cast<uInt>(size + 4))));
}

}  // namespace

std::vector<uint8_t> encodePngFast(const cv::Mat& image) {
  const bool color = image.type() == CV_8UC3;
  if (!color && image.type() != CV_16UC1) throw Error("PNG encoding: only 8-bit BGR and 16-bit gray images are supported");
  const int w = image.cols, h = image.rows;
  const size_t bytes_per_pixel = color ? 3 : 2, row_bytes = static_cast<size_t>(w) * bytes_per_pixel;
  std::vector<uint8_t> filtered((row_bytes + 1) * static_cast<size_t>(h));
  std::vector<uint8_t> prev(row_bytes, 0), cur(row_bytes);
  for (int y = 0; y < h; ++y) {
    if (color) {
      const uint8_t* p = image.ptr<uint8_t>(y);
      for (int x = 0; x < w; ++x) {
        cur[3 * x] = p[3 * x + 2];
        cur[3 * x + 1] = p[3 * x + 1];
        cur[3 * x + 2] = p[3 * x];
      }
    } else {
      const uint16_t* p = image.ptr<uint16_t>(y);
      for (int x = 0; x < w; ++x) {
        cur[2 * x] = static_cast<uint8_t>(p[x] >> 8);  // PNG samples are big-endian
        cur[2 * x + 1] = static_cast<uint8_t>(p[x] & 0xFF);
      }
    }
    uint8_t* o = &filtered[static_cast<size_t>(y) * (row_bytes + 1)];
    o[0] = kFilterUp;
    for (size_t i = 0; i < row_bytes; ++i) o[1 + i] = static_cast<uint8_t>(cur[i] - prev[i]);
    std::swap(prev, cur);
  }

  z_stream z{};
  if (deflateInit2(&z, 1, Z_DEFLATED, 15, 9, Z_HUFFMAN_ONLY) != Z_OK) throw Error("PNG encoding: zlib initialisation failed");
  std::vector<uint8_t> compressed(deflateBound(&z, static_cast<uLong>(filtered.size())));
  z.next_in = filtered.data();
  z.avail_in = static_cast<uInt>(filtered.size());
  z.next_out = compressed.data();
  z.avail_out = static_cast<uInt>(compressed.size());
  const int rc = deflate(&z, Z_FINISH);
  compressed.resize(z.total_out);
  deflateEnd(&z);
  if (rc != Z_STREAM_END) throw Error("PNG encoding: zlib deflate failed");

  std::vector<uint8_t> out = {137, 80, 78, 71, 13, 10, 26, 10};
  out.reserve(compressed.size() + 64);
  uint8_t ihdr[13];
  const uint32_t uw = static_cast<uint32_t>(w), uh = static_cast<uint32_t>(h);
  for (int i = 0; i < 4; ++i) {
    ihdr[i] = static_cast<uint8_t>(uw >> (24 - 8 * i));
    ihdr[4 + i] = static_cast<uint8_t>(uh >> (24 - 8 * i));
  }
  ihdr[8] = color ? 8 : 16;  // bit depth
  ihdr[9] = color ? 2 : 0;   // RGB or gray
  ihdr[10] = ihdr[11] = ihdr[12] = 0;  // deflate, adaptive filtering, no interlace
  chunk(out, "IHDR", ihdr, sizeof(ihdr));
  chunk(out, "IDAT", compressed.data(), compressed.size());
  chunk(out, "IEND", nullptr, 0);
  return out;
}

}  // namespace rekon::synth
