#include "rekon/common/image_io.hpp"

#include <opencv2/imgproc.hpp>

#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <limits>

#include "png_jpeg.hpp"
#include "rekon/common/error.hpp"

namespace rekon {
namespace {

void requireSize(const cv::Mat& m, int width, int height, const std::string& what) {
  if (m.cols != width || m.rows != height) {
    throw Error(what + ": image is " + std::to_string(m.cols) + "x" + std::to_string(m.rows) + " but the camera is " +
                std::to_string(width) + "x" + std::to_string(height) + "; fix camera.yaml or the image");
  }
}

uint32_t bigEndian(const uint8_t* p, int bytes) {
  uint32_t v = 0;
  for (int i = 0; i < bytes; ++i) v = (v << 8) | p[i];
  return v;
}

// Every chunk of a PNG in place with its CRC, up to IEND: libpng would report
// a cut or damaged file on stderr (a second, unclear line) before failing.
void requireCompletePng(const uint8_t* data, size_t size, const std::string& what) {
  size_t pos = 8;
  while (pos + 12 <= size) {
    const size_t length = bigEndian(data + pos, 4);
    if (length > size - pos - 12) break;
    if (::crc32(::crc32(0L, Z_NULL, 0), data + pos + 4, static_cast<uInt>(length + 4)) != bigEndian(data + pos + 8 + length, 4)) {
      std::string name(reinterpret_cast<const char*>(data) + pos + 4, 4);
      for (char& c : name) c = std::isalpha(static_cast<unsigned char>(c)) ? c : '?';
      throw Error(what + ": PNG chunk '" + name + "' fails its checksum (corrupt file); replace the file");
    }
    if (std::equal(data + pos + 4, data + pos + 8, "IEND")) return;
    pos += 12 + length;
  }
  throw Error(what + ": PNG ends before its IEND chunk (truncated); replace the file");
}

// What the header of a PNG or JPEG declares, read without decoding: a hostile
// header (a 30000x30000 image in a few bytes) is rejected by its size before
// the decoder allocates anything, and a JPEG cut short (which libjpeg would
// decode into a half-grey image with warnings) is rejected as truncated.
struct ImageHeader {
  bool png = false;
  uint32_t width = 0, height = 0;
  // Binary Netpbm (P5 grey, P6 RGB), as rekon-camera records (uncompressed:
  // a 30 Hz camera is written in a few ms per frame, PNG takes ~10x longer).
  bool netpbm = false;
  int channels = 0;
  uint32_t maxval = 0;
  size_t offset = 0;  // of the samples
};

// "P5|P6 W H MAXVAL" (comments from '#' to the end of a line), one
// whitespace byte, then exactly W*H*channels samples of 1 or 2 (big-endian)
// bytes: a file cut short is rejected as truncated.
ImageHeader readNetpbm(const uint8_t* data, size_t size, const std::string& what) {
  ImageHeader h;
  h.netpbm = true;
  h.channels = data[1] == '6' ? 3 : 1;
  size_t pos = 2;
  uint64_t values[3] = {0, 0, 0};
  for (uint64_t& v : values) {
    while (pos < size && (std::isspace(data[pos]) || data[pos] == '#')) {
      if (data[pos] == '#') while (pos < size && data[pos] != '\n') ++pos;
      else ++pos;
    }
    const size_t start = pos;
    while (pos < size && std::isdigit(data[pos]) && pos - start < 9) v = v * 10 + (data[pos++] - '0');
    if (pos == start || pos >= size || !std::isspace(data[pos])) {
      throw Error(what + ": Netpbm header is not 'P5|P6 width height maxval' (corrupt or truncated); replace the file");
    }
  }
  h.width = static_cast<uint32_t>(values[0]);
  h.height = static_cast<uint32_t>(values[1]);
  h.maxval = static_cast<uint32_t>(values[2]);
  h.offset = pos + 1;
  if (h.maxval == 0 || h.maxval > 65535) throw Error(what + ": Netpbm maxval must be 1..65535; replace the file");
  const uint64_t bytes = uint64_t{h.width} * h.height * static_cast<uint64_t>(h.channels) * (h.maxval > 255 ? 2 : 1);
  if (size - h.offset < bytes) throw Error(what + ": Netpbm image ends before its last pixel (truncated); replace the file");
  return h;
}

// The samples of a Netpbm image whose header passed readNetpbm: 16-bit grey
// (big-endian on disk) or 8-bit RGB, the latter turned into BGR.
cv::Mat decodeNetpbm(const uint8_t* data, const ImageHeader& h) {
  const int rows = static_cast<int>(h.height), cols = static_cast<int>(h.width);
  if (h.channels == 1) {
    cv::Mat m(rows, cols, CV_16UC1);
    const uint8_t* p = data + h.offset;
    for (int y = 0; y < rows; ++y) {
      auto* row = m.ptr<uint16_t>(y);
      for (int x = 0; x < cols; ++x, p += 2) row[x] = static_cast<uint16_t>((p[0] << 8) | p[1]);
    }
    return m;
  }
  cv::Mat bgr;
  cv::cvtColor(cv::Mat(rows, cols, CV_8UC3, const_cast<uint8_t*>(data + h.offset)), bgr, cv::COLOR_RGB2BGR);
  return bgr;
}

ImageHeader readHeader(const uint8_t* data, size_t size, const std::string& what) {
  static const uint8_t kPngSignature[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  ImageHeader h;
  if (size >= 8 && std::equal(kPngSignature, kPngSignature + 8, data)) {
    if (size < 33 || std::string(reinterpret_cast<const char*>(data) + 12, 4) != "IHDR") {
      throw Error(what + ": PNG without its IHDR header (corrupt or truncated); replace the file");
    }
    h.png = true;
    h.width = bigEndian(data + 16, 4);
    h.height = bigEndian(data + 20, 4);
    return h;
  }
  if (size >= 3 && data[0] == 0xFF && data[1] == 0xD8 && data[2] == 0xFF) {
    // The end-of-image marker, possibly followed by padding; entropy-coded
    // data never contains FF D9, so its absence means the file was cut.
    size_t end = size;
    while (end > 2 && (data[end - 1] == 0x00 || data[end - 1] == '\n' || data[end - 1] == '\r' || data[end - 1] == ' ')) --end;
    if (end < 4 || data[end - 2] != 0xFF || data[end - 1] != 0xD9) {
      throw Error(what + ": JPEG ends without its end-of-image marker (truncated); replace the file");
    }
    // Walk the marker segments up to the frame header (SOFn: C0-CF except C4 DHT, C8 JPG, CC DAC).
    size_t pos = 2;
    while (pos + 4 <= size) {
      if (data[pos] != 0xFF) break;
      const uint8_t marker = data[pos + 1];
      if (marker == 0xFF) {  // fill byte
        ++pos;
        continue;
      }
      if (marker == 0x01 || (marker >= 0xD0 && marker <= 0xD8)) {  // markers without a length
        pos += 2;
        continue;
      }
      const size_t length = bigEndian(data + pos + 2, 2);
      if (marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 && marker != 0xCC) {
        if (length < 7 || pos + 9 > size) break;
        h.height = bigEndian(data + pos + 5, 2);
        h.width = bigEndian(data + pos + 7, 2);
        return h;
      }
      if (length < 2) break;
      pos += 2 + length;
    }
    throw Error(what + ": JPEG without a readable frame header (corrupt or truncated); replace the file");
  }
  if (size >= 3 && data[0] == 'P' && (data[1] == '5' || data[1] == '6')) return readNetpbm(data, size, what);
  throw Error(what + ": neither PNG, JPEG nor binary PGM/PPM data (corrupt, truncated or another format); replace the file");
}

void requireDeclaredSize(const ImageHeader& h, int width, int height, const std::string& what) {
  if (h.width != static_cast<uint32_t>(width) || h.height != static_cast<uint32_t>(height)) {
    throw Error(what + ": image is " + std::to_string(h.width) + "x" + std::to_string(h.height) + " but the camera is " +
                std::to_string(width) + "x" + std::to_string(height) + "; fix camera.yaml or the image");
  }
}

}  // namespace

std::vector<uint8_t> readFileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path + ": cannot open file; check that it exists and is readable");
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), {});
}

cv::Mat decodeDepthPng(const uint8_t* data, size_t size, int width, int height, const std::string& what) {
  if (size == 0) throw Error(what + ": empty image data; the file or message is truncated");
  const ImageHeader h = readHeader(data, size, what);
  if (h.netpbm) {
    requireDeclaredSize(h, width, height, what);
    if (h.channels != 1 || h.maxval <= 255) {
      throw Error(what + ": depth must be 16-bit single-channel (PNG or P5 PGM with maxval 65535); convert the depth image");
    }
    return decodeNetpbm(data, h);
  }
  if (!h.png) throw Error(what + ": depth must be a 16-bit single-channel PNG, found a JPEG; convert the depth image");
  requireDeclaredSize(h, width, height, what);
  requireCompletePng(data, size, what);
  cv::Mat m = detail::decodePngGray16(data, size, what);
  requireSize(m, width, height, what);
  return m;
}

cv::Mat decodeColor(const uint8_t* data, size_t size, int width, int height, const std::string& what) {
  if (size == 0) throw Error(what + ": empty image data; the file or message is truncated");
  const ImageHeader h = readHeader(data, size, what);
  requireDeclaredSize(h, width, height, what);
  if (h.netpbm) {
    if (h.channels != 3 || h.maxval != 255) throw Error(what + ": color must be 8-bit RGB (P6 PPM with maxval 255); convert the color image");
    return decodeNetpbm(data, h);
  }
  if (h.png) requireCompletePng(data, size, what);
  cv::Mat m = h.png ? detail::decodePngBgr(data, size, what) : detail::decodeJpegBgr(data, size, what);
  requireSize(m, width, height, what);
  return m;
}

cv::Mat readDepthImage(const std::string& path, int width, int height) {
  const auto bytes = readFileBytes(path);
  return decodeDepthPng(bytes.data(), bytes.size(), width, height, path);
}

cv::Mat readColorImage(const std::string& path, int width, int height) {
  const auto bytes = readFileBytes(path);
  return decodeColor(bytes.data(), bytes.size(), width, height, path);
}

// Level 1: the fastest zlib setting; frames are re-encoded on every publish.
std::vector<uint8_t> encodePng(const cv::Mat& image) { return detail::encodePngImage(image, 1); }

std::vector<uint8_t> encodeJpeg(const cv::Mat& image, int quality) { return detail::encodeJpegImage(image, quality); }

void writeImage(const std::string& path, const cv::Mat& image) {
  std::string ext = std::filesystem::path(path).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (ext == ".ppm" || ext == ".pgm") return writeNetpbm(path, image);
  std::vector<uint8_t> bytes;
  if (ext == ".png") bytes = encodePng(image);
  else if (ext == ".jpg" || ext == ".jpeg") bytes = encodeJpeg(image);
  else throw Error(path + ": cannot write an image with this extension; use .png, .jpg, .ppm or .pgm");
  std::ofstream out(path, std::ios::binary);
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
  if (!out.flush()) throw Error(path + ": cannot write image; check the output folder");
}

void writeNetpbm(const std::string& path, const cv::Mat& image) {
  const bool depth = image.type() == CV_16UC1;
  if (!depth && image.type() != CV_8UC3) throw Error(path + ": only 16-bit depth or 8-bit BGR images are written as Netpbm");
  std::vector<uint8_t> samples(image.total() * image.elemSize());
  uint8_t* p = samples.data();
  for (int y = 0; y < image.rows; ++y) {
    if (depth) {
      const auto* row = image.ptr<uint16_t>(y);
      for (int x = 0; x < image.cols; ++x, p += 2) {
        p[0] = static_cast<uint8_t>(row[x] >> 8);
        p[1] = static_cast<uint8_t>(row[x] & 0xff);
      }
    } else {
      const auto* row = image.ptr<uint8_t>(y);
      for (int x = 0; x < image.cols; ++x, p += 3) {
        p[0] = row[3 * x + 2];
        p[1] = row[3 * x + 1];
        p[2] = row[3 * x];
      }
    }
  }
  std::ofstream out(path, std::ios::binary);
  out << (depth ? "P5\n" : "P6\n") << image.cols << " " << image.rows << "\n" << (depth ? 65535 : 255) << "\n";
  out.write(reinterpret_cast<const char*>(samples.data()), static_cast<std::streamsize>(samples.size()));
  if (!out.flush()) throw Error(path + ": cannot write the image (disk full or not writable?)");
}

}  // namespace rekon
