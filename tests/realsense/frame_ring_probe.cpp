// frame_ring_probe: the C++ receivers' FrameRingReader, driven line by line
// from stdin by test_frame_ring.py, which writes the ring from Python
// (rekon-realsense's writer). Commands, one answer line each:
//   read SEGMENT SLOT GENERATION OUTFILE  -> "ok ID TIMESTAMP W H" (depth then
//                                            BGR colour bytes in OUTFILE), or
//                                            the status ("overwritten", "torn")
//   torn SEGMENT SLOT GENERATION          -> "copying" once the frame is
//                                            copied, then waits for a line
//                                            (the test writes the slot again
//                                            meanwhile), then the status
// An attach error is "error: " and its one line.
#include <cstdio>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>
#include <string>

#include "rekon/common/error.hpp"
#include "rekon/common/frame_ring.hpp"

namespace {

const char* statusWord(rekon::FrameRingReader::Status s) {
  switch (s) {
    case rekon::FrameRingReader::Status::kOk: return "ok";
    case rekon::FrameRingReader::Status::kOverwritten: return "overwritten";
    case rekon::FrameRingReader::Status::kTorn: return "torn";
    case rekon::FrameRingReader::Status::kBadReference: return "bad-reference";
  }
  return "unknown";
}

}  // namespace

int main() {
  std::map<std::string, std::unique_ptr<rekon::FrameRingReader>> rings;
  std::string line;
  while (std::getline(std::cin, line)) {
    std::istringstream in(line);
    std::string command, segment, out_file;
    int slot = 0;
    uint64_t generation = 0;
    in >> command >> segment >> slot >> generation >> out_file;
    try {
      auto& ring = rings[segment];
      if (!ring) ring = std::make_unique<rekon::FrameRingReader>(segment);
      rekon::RgbdFrame frame;
      rekon::FrameRingReader::Status status;
      if (command == "torn") {
        status = ring->read(slot, generation, &frame, [] {
          std::cout << "copying" << std::endl;
          std::string go;
          std::getline(std::cin, go);
        });
      } else {
        status = ring->read(slot, generation, &frame);
      }
      if (status != rekon::FrameRingReader::Status::kOk || command != "read") {
        std::cout << statusWord(status) << std::endl;
        continue;
      }
      std::ofstream f(out_file, std::ios::binary);
      f.write(reinterpret_cast<const char*>(frame.depth.data), static_cast<std::streamsize>(frame.depth.total() * 2));
      f.write(reinterpret_cast<const char*>(frame.color.data), static_cast<std::streamsize>(frame.color.total() * 3));
      char text[128];
      std::snprintf(text, sizeof text, "ok %lld %.17g %d %d", static_cast<long long>(frame.id), frame.timestamp,
                    frame.depth.cols, frame.depth.rows);
      std::cout << text << std::endl;
    } catch (const rekon::Error& e) {
      rings.erase(segment);
      std::cout << "error: " << e.what() << std::endl;
    }
  }
  return 0;
}
