#include "rekon/progress/progress_line.hpp"

#include <fmt/format.h>
#include <spdlog/sinks/base_sink.h>
#include <spdlog/spdlog.h>
#include <sys/ioctl.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>

namespace rekon {
namespace {

// Clears the progress line before the logger's own sink writes a message.
class ClearingSink : public spdlog::sinks::base_sink<std::mutex> {
 public:
  explicit ClearingSink(ProgressLine& line) : line_(line) {}

 protected:
  void sink_it_(const spdlog::details::log_msg&) override { line_.clear(); }
  void flush_() override {}

 private:
  ProgressLine& line_;
};

// The terminal's width (a longer line would wrap and break the rewriting).
size_t columns(std::FILE* out) {
  winsize w{};
  if (ioctl(fileno(out), TIOCGWINSZ, &w) == 0 && w.ws_col > 10) return w.ws_col - 1;
  return 99;
}

double secondsBetween(std::chrono::steady_clock::time_point a, std::chrono::steady_clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

}  // namespace

ProgressLine::ProgressLine(std::FILE* out) : ProgressLine(out, isatty(fileno(out)) != 0) {}

ProgressLine::ProgressLine(std::FILE* out, bool tty) : out_(out), tty_(tty) {
  if (!tty_) return;
  clearing_sink_ = std::make_shared<ClearingSink>(*this);
  auto& sinks = spdlog::default_logger()->sinks();
  sinks.insert(sinks.begin(), clearing_sink_);
}

ProgressLine::~ProgressLine() {
  if (clearing_sink_) {
    auto& sinks = spdlog::default_logger()->sinks();
    sinks.erase(std::remove(sinks.begin(), sinks.end(), clearing_sink_), sinks.end());
  }
  std::lock_guard<std::mutex> lock(mutex_);
  if (tty_ && shown_) std::fputs("\n", out_);
}

void ProgressLine::update(const std::string& text) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto now = std::chrono::steady_clock::now();
  if (finished_ || secondsBetween(last_, now) < (tty_ ? kTtyEveryS : kPlainEveryS)) return;
  last_ = now;
  show(text);
}

void ProgressLine::finish(const std::string& text) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (finished_) return;
  show(text);
  if (tty_) std::fputs("\n", out_);
  std::fflush(out_);
  shown_ = false;
  finished_ = true;
}

void ProgressLine::clear() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!tty_ || !shown_) return;
  std::fputs("\r\033[K", out_);
  std::fflush(out_);
  shown_ = false;
}

void ProgressLine::show(const std::string& text) {
  if (tty_) {
    std::fprintf(out_, "\r\033[K%s", text.substr(0, columns(out_)).c_str());
    shown_ = true;
  } else {
    std::fprintf(out_, "%s\n", text.c_str());
  }
  std::fflush(out_);
}

std::string frameProgress(long long done, long long total, double frames_per_s, double realtime_factor, bool ended) {
  std::string s = total > 0 ? fmt::format("frame {}/{} ({:.0f} %)", done, total, 100.0 * static_cast<double>(done) / static_cast<double>(total))
                            : fmt::format("frame {}", done);
  if (frames_per_s > 0) s += fmt::format(", {:.1f} fps", frames_per_s);
  if (realtime_factor > 0) s += fmt::format(", {:.2f}x realtime", realtime_factor);
  if (!ended && frames_per_s > 0 && total > done)
    s += fmt::format(", ETA {:.0f} s", std::ceil(static_cast<double>(total - done) / frames_per_s));
  return s;
}

}  // namespace rekon
