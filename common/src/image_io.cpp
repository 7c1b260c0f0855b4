#include "rekon/common/image_io.hpp"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <filesystem>
#include <fstream>

#include "rekon/common/error.hpp"

namespace rekon {
namespace {

void requireSize(const cv::Mat& m, int width, int height, const std::string& what) {
  if (m.cols != width || m.rows != height) {
    throw Error(what + ": image is " + std::to_string(m.cols) + "x" + std::to_string(m.rows) + " but the camera is " +
                std::to_string(width) + "x" + std::to_string(height) + "; fix camera.yaml or the image");
  }
}

cv::Mat decode(const uint8_t* data, size_t size, int flags, const std::string& what) {
  if (size == 0) throw Error(what + ": empty image data; the file or message is truncated");
  cv::Mat m;
  try {
    m = cv::imdecode(cv::Mat(1, static_cast<int>(size), CV_8UC1, const_cast<uint8_t*>(data)), flags);
  } catch (const cv::Exception&) {
    m.release();
  }
  if (m.empty()) throw Error(what + ": not a decodable PNG/JPEG (corrupt or truncated); replace the file");
  return m;
}

}  // namespace

std::vector<uint8_t> readFileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path + ": cannot open file; check that it exists and is readable");
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), {});
}

cv::Mat decodeDepthPng(const uint8_t* data, size_t size, int width, int height, const std::string& what) {
  cv::Mat m = decode(data, size, cv::IMREAD_ANYDEPTH | cv::IMREAD_GRAYSCALE, what);
  if (m.type() != CV_16UC1) {
    throw Error(what + ": depth must be a 16-bit single-channel PNG, found " + std::to_string(m.elemSize1() * 8) +
                "-bit with " + std::to_string(m.channels()) + " channel(s); convert the depth image");
  }
  requireSize(m, width, height, what);
  return m;
}

cv::Mat decodeColor(const uint8_t* data, size_t size, int width, int height, const std::string& what) {
  cv::Mat m = decode(data, size, cv::IMREAD_COLOR, what);
  if (m.type() != CV_8UC3) throw Error(what + ": color must be 8-bit; convert the color image");
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

std::vector<uint8_t> encodePng(const cv::Mat& image) {
  std::vector<uint8_t> out;
  // Level 1: the fastest zlib setting; frames are re-encoded on every publish.
  if (!cv::imencode(".png", image, out, {cv::IMWRITE_PNG_COMPRESSION, 1})) throw Error("PNG encoding failed");
  return out;
}

std::vector<uint8_t> encodeJpeg(const cv::Mat& image, int quality) {
  std::vector<uint8_t> out;
  if (!cv::imencode(".jpg", image, out, {cv::IMWRITE_JPEG_QUALITY, quality})) throw Error("JPEG encoding failed");
  return out;
}

void writeImage(const std::string& path, const cv::Mat& image) {
  bool ok = false;
  try {
    ok = cv::imwrite(path, image);
  } catch (const cv::Exception&) {
    ok = false;
  }
  if (!ok) throw Error(path + ": cannot write image; check the output folder and the file extension");
}

}  // namespace rekon
