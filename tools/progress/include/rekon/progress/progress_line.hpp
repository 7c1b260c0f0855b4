#pragma once
// Progress of a long command on the terminal (rekon run, demo, synth). On a
// TTY it is one line rewritten in place, at most kTtyEveryS apart, and a log
// line written meanwhile first clears it (no half-overwritten lines); on
// anything else (a pipe, a log file) it is a plain line every kPlainEveryS.
#include <chrono>
#include <cstdio>
#include <memory>
#include <mutex>
#include <string>

namespace spdlog::sinks {
class sink;
}

namespace rekon {

class ProgressLine {
 public:
  static constexpr double kTtyEveryS = 0.25;
  static constexpr double kPlainEveryS = 5.0;

  // `tty`: rewrite in place (default: whether `out` is a terminal).
  explicit ProgressLine(std::FILE* out = stderr);
  ProgressLine(std::FILE* out, bool tty);
  ~ProgressLine();
  ProgressLine(const ProgressLine&) = delete;
  ProgressLine& operator=(const ProgressLine&) = delete;

  // Shows `text` when the last showing is old enough (any thread).
  void update(const std::string& text);
  // Shows `text` now and ends the line: what follows starts on a fresh one.
  void finish(const std::string& text);
  // Clears a line shown on a TTY (before a log line is written).
  void clear();

 private:
  void show(const std::string& text);
  std::FILE* out_;
  bool tty_;
  bool shown_ = false, finished_ = false;
  std::chrono::steady_clock::time_point last_{};
  std::mutex mutex_;
  std::shared_ptr<spdlog::sinks::sink> clearing_sink_;  // in the default logger while the line lives (TTY)
};

// "frame 123/300 (41 %), 28.5 fps, 0.95x realtime, ETA 6 s": `total` 0 for an
// open end (a live camera), `realtime_factor` 0 where there is none (a camera,
// an unknown recorded rate). `ended`: the last line of work that stopped (done
// or interrupted), without an ETA.
std::string frameProgress(long long done, long long total, double frames_per_s, double realtime_factor = 0.0,
                          bool ended = false);

}  // namespace rekon
