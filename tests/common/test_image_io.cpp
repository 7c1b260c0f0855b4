// Image decoding of hostile bytes: every broken input is one rekon::Error that
// names the source and says what is wrong, before any large allocation.
#include <gtest/gtest.h>

#include <cstdio>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <string>
#include <vector>

#include "rekon/common/error.hpp"
#include "rekon/common/image_io.hpp"
#include "test_support.hpp"

namespace {

constexpr int kWidth = 32, kHeight = 24;

cv::Mat colorImage() {
  cv::Mat m(kHeight, kWidth, CV_8UC3);
  cv::randu(m, 0, 255);
  return m;
}

cv::Mat depthImage() {
  cv::Mat m(kHeight, kWidth, CV_16UC1);
  cv::randu(m, 500, 4000);
  return m;
}

// The message of the rekon::Error that decoding `bytes` throws ("" if none).
std::string colorError(const std::vector<uint8_t>& bytes) {
  try {
    rekon::decodeColor(bytes.data(), bytes.size(), kWidth, kHeight, "frame 7 color");
  } catch (const rekon::Error& e) {
    return e.what();
  }
  return "";
}

std::string depthError(const std::vector<uint8_t>& bytes) {
  try {
    rekon::decodeDepthPng(bytes.data(), bytes.size(), kWidth, kHeight, "frame 7 depth");
  } catch (const rekon::Error& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(ImageIo, ValidPngAndJpegDecodeToTheirSize) {
  EXPECT_EQ(colorError(rekon::encodePng(colorImage())), "");
  EXPECT_EQ(colorError(rekon::encodeJpeg(colorImage())), "");
  const cv::Mat depth = depthImage();
  const auto png = rekon::encodePng(depth);
  const cv::Mat back = rekon::decodeDepthPng(png.data(), png.size(), kWidth, kHeight, "depth");
  EXPECT_EQ(cv::norm(back, depth, cv::NORM_INF), 0.0);  // PNG is lossless
}

TEST(ImageIo, TruncatedJpegIsAnErrorNotAHalfGreyImage) {
  auto jpeg = rekon::encodeJpeg(colorImage());
  jpeg.resize(jpeg.size() * 2 / 3);
  const std::string e = colorError(jpeg);
  EXPECT_NE(e.find("frame 7 color"), std::string::npos) << e;
  EXPECT_NE(e.find("truncated"), std::string::npos) << e;
}

TEST(ImageIo, TruncatedPngIsAnErrorAtEveryLength) {
  const auto png = rekon::encodePng(depthImage());
  for (size_t n = 1; n < png.size(); n += 7) {
    const std::vector<uint8_t> cut(png.begin(), png.begin() + static_cast<long>(n));
    EXPECT_NE(depthError(cut).find("frame 7 depth"), std::string::npos) << "cut at " << n;
  }
}

TEST(ImageIo, HugeDeclaredSizeIsRejectedFromTheHeader) {
  // A 30000x30000 header in a few bytes must not make the decoder allocate 2.7 GB.
  auto png = rekon::encodePng(colorImage());
  png[16] = 0, png[17] = 0, png[18] = 0x75, png[19] = 0x30;  // IHDR width 30000
  png[20] = 0, png[21] = 0, png[22] = 0x75, png[23] = 0x30;  // IHDR height 30000
  EXPECT_NE(colorError(png).find("30000x30000"), std::string::npos) << colorError(png);
  auto jpeg = rekon::encodeJpeg(colorImage());
  for (size_t i = 2; i + 9 < jpeg.size(); ++i) {
    if (jpeg[i] == 0xFF && jpeg[i + 1] == 0xC0) {  // baseline frame header: height, width at +5, +7
      jpeg[i + 5] = 0x75, jpeg[i + 6] = 0x30, jpeg[i + 7] = 0x75, jpeg[i + 8] = 0x30;
      break;
    }
  }
  EXPECT_NE(colorError(jpeg).find("30000x30000"), std::string::npos) << colorError(jpeg);
}

TEST(ImageIo, OtherFormatsAndGarbageAreNamed) {
  std::vector<uint8_t> bmp;
  cv::imencode(".bmp", colorImage(), bmp);
  EXPECT_NE(colorError(bmp).find("neither PNG, JPEG nor binary PGM/PPM"), std::string::npos) << colorError(bmp);
  EXPECT_NE(colorError({1, 2, 3}).find("neither PNG, JPEG nor binary PGM/PPM"), std::string::npos);
  EXPECT_NE(colorError({}).find("empty image data"), std::string::npos);
}

// rekon-camera records uncompressed PGM depth and PPM color: written and read
// back bit for bit, and a cut, mislabelled or hostile Netpbm file is one line.
std::vector<uint8_t> netpbmBytes(const cv::Mat& image) {
  rekon::test::TempDir dir;
  const std::string path = dir / "image.pnm";
  rekon::writeNetpbm(path, image);
  return rekon::readFileBytes(path);
}

TEST(ImageIo, NetpbmRoundTripsBitForBit) {
  const cv::Mat depth_in = depthImage(), color_in = colorImage();
  const auto pgm = netpbmBytes(depth_in);
  const auto ppm = netpbmBytes(color_in);
  ASSERT_EQ(std::string(pgm.begin(), pgm.begin() + 2), "P5");
  ASSERT_EQ(std::string(ppm.begin(), ppm.begin() + 2), "P6");
  const cv::Mat depth = rekon::decodeDepthPng(pgm.data(), pgm.size(), kWidth, kHeight, "pgm");
  const cv::Mat color = rekon::decodeColor(ppm.data(), ppm.size(), kWidth, kHeight, "ppm");
  EXPECT_EQ(cv::norm(depth, depth_in, cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(color, color_in, cv::NORM_INF), 0.0);
  // A comment in the header, as other writers put one there.
  std::string text(ppm.begin(), ppm.end());
  text.insert(3, "# written elsewhere\n");
  EXPECT_EQ(colorError(std::vector<uint8_t>(text.begin(), text.end())), "");
}

TEST(ImageIo, BadNetpbmIsOneLine) {
  auto pgm = netpbmBytes(depthImage());
  pgm.pop_back();
  EXPECT_NE(depthError(pgm).find("truncated"), std::string::npos) << depthError(pgm);
  EXPECT_NE(depthError(netpbmBytes(colorImage())).find("16-bit single-channel"), std::string::npos);
  EXPECT_NE(colorError(netpbmBytes(depthImage())).find("8-bit RGB"), std::string::npos);
  // A hostile header is rejected by its size before anything is allocated.
  const std::string huge = "P6\n999999999 999999999\n255\n";
  EXPECT_NE(colorError(std::vector<uint8_t>(huge.begin(), huge.end())).find("truncated"), std::string::npos);
  const std::string garbage = "P5 32 x4 65535\n";
  EXPECT_NE(depthError(std::vector<uint8_t>(garbage.begin(), garbage.end())).find("Netpbm header"), std::string::npos);
  const std::string zero = "P5 32 24 0\n";
  EXPECT_NE(depthError(std::vector<uint8_t>(zero.begin(), zero.end())).find("maxval"), std::string::npos);
}

TEST(ImageIo, DepthMustBeA16BitPng) {
  EXPECT_NE(depthError(rekon::encodeJpeg(colorImage())).find("found a JPEG"), std::string::npos);
  cv::Mat eight(kHeight, kWidth, CV_8UC1, cv::Scalar(3));
  EXPECT_NE(depthError(rekon::encodePng(eight)).find("16-bit"), std::string::npos);
}

TEST(ImageIo, WrongSizeNamesBothSizes) {
  cv::Mat small(kHeight - 1, kWidth, CV_8UC3, cv::Scalar(1, 2, 3));
  const std::string e = colorError(rekon::encodePng(small));
  EXPECT_NE(e.find("32x23"), std::string::npos) << e;
  EXPECT_NE(e.find("32x24"), std::string::npos) << e;
}

// image_io decodes and encodes with libpng and libjpeg directly; OpenCV's
// imgcodecs (linked into this test only) is the reference it must agree with.
namespace {

std::vector<uint8_t> openCvEncoded(const std::string& ext, const cv::Mat& image) {
  std::vector<uint8_t> bytes;
  EXPECT_TRUE(cv::imencode(ext, image, bytes));
  return bytes;
}

cv::Mat decodedColor(const std::vector<uint8_t>& bytes) {
  return rekon::decodeColor(bytes.data(), bytes.size(), kWidth, kHeight, "test");
}

bool same(const cv::Mat& a, const cv::Mat& b) {
  return a.type() == b.type() && a.size() == b.size() && cv::norm(a, b, cv::NORM_INF) == 0;
}

}  // namespace

TEST(ImageIo, DecodesEveryPngAndJpegKindAsOpenCvDoes) {
  cv::Mat gray(kHeight, kWidth, CV_8UC1), bgra(kHeight, kWidth, CV_8UC4), color16(kHeight, kWidth, CV_16UC3);
  cv::randu(gray, 0, 255);
  cv::randu(bgra, 0, 255);
  cv::randu(color16, 0, 65535);
  const std::vector<std::pair<std::string, cv::Mat>> cases = {
      {".png", colorImage()}, {".png", gray}, {".png", bgra}, {".png", color16}, {".jpg", colorImage()}, {".jpg", gray}};
  for (const auto& [ext, image] : cases) {
    const std::vector<uint8_t> bytes = openCvEncoded(ext, image);
    const cv::Mat reference = cv::imdecode(bytes, cv::IMREAD_COLOR);
    EXPECT_TRUE(same(decodedColor(bytes), reference)) << ext << " of type " << image.type();
  }
  const std::vector<uint8_t> depth = openCvEncoded(".png", depthImage());
  const cv::Mat reference = cv::imdecode(depth, cv::IMREAD_ANYDEPTH);
  EXPECT_TRUE(same(rekon::decodeDepthPng(depth.data(), depth.size(), kWidth, kHeight, "test"), reference));
}

TEST(ImageIo, EncodedImagesReadBackInOpenCvAsWritten) {
  cv::Mat gray(kHeight, kWidth, CV_8UC1), bgra(kHeight, kWidth, CV_8UC4);
  cv::randu(gray, 0, 255);
  cv::randu(bgra, 0, 255);
  for (const cv::Mat& image : {colorImage(), gray, bgra, depthImage()}) {
    EXPECT_TRUE(same(cv::imdecode(rekon::encodePng(image), cv::IMREAD_UNCHANGED), image)) << image.type();
  }
  // JPEG is lossy: at OpenCV's default quality (95, rekon's too) ours is as close to the original as OpenCV's.
  const cv::Mat smooth = [] {
    cv::Mat m(kHeight, kWidth, CV_8UC3);
    for (int y = 0; y < kHeight; ++y)
      for (int x = 0; x < kWidth; ++x) m.at<cv::Vec3b>(y, x) = cv::Vec3b(x * 8, y * 10, (x + y) * 4);
    return m;
  }();
  const cv::Mat ours = cv::imdecode(rekon::encodeJpeg(smooth), cv::IMREAD_COLOR);
  const cv::Mat theirs = cv::imdecode(openCvEncoded(".jpg", smooth), cv::IMREAD_COLOR);
  ASSERT_FALSE(ours.empty());
  const double ours_error = cv::norm(ours, smooth, cv::NORM_L1) / static_cast<double>(smooth.total());
  const double their_error = cv::norm(theirs, smooth, cv::NORM_L1) / static_cast<double>(smooth.total());
  // Measured equal (2.690 both, libjpeg-turbo 2.1.5); 0.5 leaves room for encoder settings (e.g. OpenCV choosing
  // another chroma subsampling) without letting through swapped channels (this image's differ by tens of levels).
  std::printf("JPEG at quality 95, mean absolute error per pixel: ours %.3f, OpenCV's %.3f\n", ours_error, their_error);
  EXPECT_LE(ours_error, their_error + 0.5) << "mean absolute error per pixel (3 channels), ours against OpenCV's";
}
