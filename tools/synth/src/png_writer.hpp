#pragma once
// A minimal, fast PNG encoder for sequence writing: every row uses the "Up"
// filter and deflate runs Huffman-only, which on noisy sensor images is about
// as small as libpng's adaptive filtering and takes about half the time.
#include <opencv2/core/mat.hpp>

#include <cstdint>
#include <vector>

namespace rekon::synth {

// CV_8UC3 (BGR, written as RGB) or CV_16UC1 (written as 16-bit gray).
std::vector<uint8_t> encodePngFast(const cv::Mat& image);

}  // namespace rekon::synth
