// What a long run measured, per time bucket, from the tables its services
// and the bench write as they go; the plots and the goals of issue 49.
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>

#include "rekon/common/error.hpp"
#include "rekon/longrun/longrun.hpp"

namespace rekon::longrun {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Rows of a CSV with a header line, as named columns; a missing file has none.
struct Table {
  std::vector<std::string> header;
  std::vector<std::vector<std::string>> rows;
  int column(const std::string& name) const {
    const auto it = std::find(header.begin(), header.end(), name);
    return it == header.end() ? -1 : static_cast<int>(it - header.begin());
  }
  double number(size_t row, int col) const {
    if (col < 0 || static_cast<size_t>(col) >= rows[row].size()) return kNaN;
    try {
      return std::stod(rows[row][static_cast<size_t>(col)]);
    } catch (const std::exception&) {
      return kNaN;
    }
  }
};

std::vector<std::string> split(const std::string& line) {
  std::vector<std::string> out;
  std::stringstream ss(line);
  std::string cell;
  while (std::getline(ss, cell, ',')) out.push_back(cell);
  return out;
}

Table readTable(const std::string& path) {
  Table t;
  std::ifstream in(path);
  std::string line;
  if (!std::getline(in, line)) return t;
  t.header = split(line);
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    auto cells = split(line);
    if (cells.size() == t.header.size()) t.rows.push_back(std::move(cells));  // a row cut short by a kill is left out
  }
  return t;
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return kNaN;
  // Nearest rank.
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(std::max(0.0, std::ceil(q * static_cast<double>(v.size())) - 1)));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}
double mean(const std::vector<double>& v) {
  if (v.empty()) return kNaN;
  double s = 0;
  for (double x : v) s += x;
  return s / static_cast<double>(v.size());
}
double maxOf(const std::vector<double>& v) { return v.empty() ? kNaN : *std::max_element(v.begin(), v.end()); }

}  // namespace

std::vector<Bucket> readBuckets(const std::string& dir, double bucket_s, double fps) {
  if (!(bucket_s > 0) || !(fps > 0)) throw Error("longrun: bucket and frame rate must be positive");
  std::vector<Bucket> b;
  struct Samples {
    std::vector<double> latency, integrate, solve, round, loop_check;
  };
  std::vector<Samples> s;
  auto at = [&](double t) -> Bucket& {
    const size_t i = static_cast<size_t>(std::max(0.0, std::floor(t / bucket_s)));
    while (b.size() <= i) {
      Bucket n;
      n.t0_s = static_cast<double>(b.size()) * bucket_s;
      n.latency_p50_ms = n.latency_p95_ms = n.integrate_ms_mean = n.solve_ms_mean = n.solve_ms_max = n.round_ms_mean =
          n.round_ms_max = n.loop_check_ms_mean = n.render_ms_mean = kNaN;
      b.push_back(n);
      s.emplace_back();
    }
    return b[i];
  };
  auto samples = [&](double t) -> Samples& {
    at(t);
    return s[static_cast<size_t>(std::max(0.0, std::floor(t / bucket_s)))];
  };
  const std::filesystem::path d(dir);
  {  // capture-to-pose, per frame posed
    const Table t = readTable((d / "player_latency.csv").string());
    const int id = t.column("frame_id"), ms = t.column("latency_ms");
    for (size_t r = 0; r < t.rows.size(); ++r) {
      const double time = t.number(r, id) / fps;
      at(time).frames_posed += 1;
      samples(time).latency.push_back(t.number(r, ms));
    }
  }
  {  // the source's cumulative counts, once a second
    const Table t = readTable((d / "source_counts.csv").string());
    const int due = t.column("frames_due"), sent = t.column("sent"), drop = t.column("dropped"),
              skip = t.column("skipped_late"), ren = t.column("render_ms_mean");
    double p_due = 0, p_sent = 0, p_drop = 0, p_skip = 0;
    std::vector<std::vector<double>> render;
    for (size_t r = 0; r < t.rows.size(); ++r) {
      // On the frames' axis (the next frame due / fps), as the other tables: seconds of play, not since the start.
      Bucket& k = at(std::max(0.0, t.number(r, due) - 1) / fps);
      k.frames_due += t.number(r, due) - p_due;
      k.frames_sent += t.number(r, sent) - p_sent;
      k.frames_dropped += t.number(r, drop) - p_drop;
      k.frames_skipped += t.number(r, skip) - p_skip;
      p_due = t.number(r, due), p_sent = t.number(r, sent), p_drop = t.number(r, drop), p_skip = t.number(r, skip);
      const size_t i = static_cast<size_t>(&k - b.data());
      if (render.size() <= i) render.resize(i + 1);
      if (t.number(r, ren) > 0) render[i].push_back(t.number(r, ren));
    }
    for (size_t i = 0; i < render.size(); ++i) b[i].render_ms_mean = mean(render[i]);
  }
  {  // frames fused and their integration time; a restarted mapper adds its rows, and a frame it was sent
     // again (after its store's newest) is counted once
    const Table t = readTable((d / "mapper_timing.csv").string());
    const int id = t.column("frame_id"), ms = t.column("integrate_ms");
    std::set<double> fused;
    for (size_t r = 0; r < t.rows.size(); ++r) {
      const double time = t.number(r, id) / fps;
      if (fused.insert(t.number(r, id)).second) at(time).frames_fused += 1;
      samples(time).integrate.push_back(t.number(r, ms));
    }
  }
  {  // correction rounds that re-integrated something (the final pass is the end of run, not a round)
    const Table t = readTable((d / "mapper_reintegration.csv").string());
    const int time = t.column("time_s"), ms = t.column("ms"), fin = t.column("final_pass"),
              kfs = t.column("keyframes_reintegrated");
    for (size_t r = 0; r < t.rows.size(); ++r)
      if (t.number(r, fin) == 0 && t.number(r, kfs) > 0) samples(t.number(r, time)).round.push_back(t.number(r, ms));
  }
  {  // optimiser solves, at the frame they followed
    const Table t = readTable((d / "optimiser_timing.csv").string());
    const int id = t.column("frame_id"), ms = t.column("ms");
    for (size_t r = 0; r + 1 < t.rows.size(); ++r)  // the last is the final optimisation
      if (t.number(r, id) >= 0) samples(t.number(r, id) / fps).solve.push_back(t.number(r, ms));
  }
  {  // the tracker's loop checks, at the frame of the keyframe checked
    const Table t = readTable((d / "tracker_loop_checks.csv").string());
    const int id = t.column("frame_id"), ms = t.column("ms");
    for (size_t r = 0; r < t.rows.size(); ++r) samples(t.number(r, id) / fps).loop_check.push_back(t.number(r, ms));
  }
  {  // resident memory per service, sampled by the bench
    const Table t = readTable((d / "longrun_rss.csv").string());
    const int sec = t.column("seconds"), svc = t.column("service"), mb = t.column("rss_mb");
    for (size_t r = 0; r < t.rows.size(); ++r) {
      double& v = at(t.number(r, sec)).rss_mb[t.rows[r][static_cast<size_t>(svc)]];
      v = std::max(v, t.number(r, mb));
    }
  }
  {  // the mapper's voxel tiers, from its live numbers on the bus
    const Table t = readTable((d / "longrun_tiers.csv").string());
    const int sec = t.column("seconds");
    for (size_t r = 0; r < t.rows.size(); ++r)
      for (const char* tier : {"active_mb", "host_mb", "on_disk_mb"}) {
        double& v = at(t.number(r, sec)).tier_mb[tier];
        v = std::max(v, t.number(r, t.column(tier)));
      }
  }
  for (size_t i = 0; i < b.size(); ++i) {
    b[i].latency_p50_ms = percentile(s[i].latency, 0.5);
    b[i].latency_p95_ms = percentile(s[i].latency, 0.95);
    b[i].integrate_ms_mean = mean(s[i].integrate);
    b[i].solve_ms_mean = mean(s[i].solve);
    b[i].solve_ms_max = maxOf(s[i].solve);
    b[i].round_ms_mean = mean(s[i].round);
    b[i].round_ms_max = maxOf(s[i].round);
    b[i].loop_check_ms_mean = mean(s[i].loop_check);
  }
  return b;
}

namespace {
std::string num(double v) { return std::isnan(v) ? "" : fmt::format("{:.4g}", v); }

std::vector<std::string> services(const std::vector<Bucket>& b) {
  std::vector<std::string> out;
  for (const auto& k : b)
    for (const auto& [name, mb] : k.rss_mb)
      if (std::find(out.begin(), out.end(), name) == out.end()) out.push_back(name);
  return out;
}
}  // namespace

void writeBucketsCsv(const std::vector<Bucket>& b, const std::string& path) {
  const auto names = services(b);
  std::ofstream out(path + ".tmp");
  out << "minute_start,frames_due,frames_sent,frames_dropped,frames_skipped,frames_posed,frames_fused,"
         "latency_p50_ms,latency_p95_ms,integrate_ms_mean,solve_ms_mean,solve_ms_max,round_ms_mean,round_ms_max,"
         "loop_check_ms_mean,render_ms_mean,voxels_active_mb,voxels_host_mb,voxels_on_disk_mb";
  for (const auto& n : names) out << ",rss_mb_" << n;
  out << "\n";
  for (const auto& k : b) {
    auto tier = [&](const char* t) { return k.tier_mb.count(t) ? k.tier_mb.at(t) : kNaN; };
    out << num(k.t0_s / 60.0) << ',' << num(k.frames_due) << ',' << num(k.frames_sent) << ',' << num(k.frames_dropped) << ','
        << num(k.frames_skipped) << ',' << num(k.frames_posed) << ',' << num(k.frames_fused) << ',' << num(k.latency_p50_ms)
        << ',' << num(k.latency_p95_ms) << ',' << num(k.integrate_ms_mean) << ',' << num(k.solve_ms_mean) << ','
        << num(k.solve_ms_max) << ',' << num(k.round_ms_mean) << ',' << num(k.round_ms_max) << ','
        << num(k.loop_check_ms_mean) << ',' << num(k.render_ms_mean) << ',' << num(tier("active_mb")) << ',' << num(tier("host_mb")) << ','
        << num(tier("on_disk_mb"));
    for (const auto& n : names) out << ',' << num(k.rss_mb.count(n) ? k.rss_mb.at(n) : kNaN);
    out << "\n";
  }
  out.close();
  if (!out) throw Error(path + ": cannot write; check the output folder");
  std::filesystem::rename(path + ".tmp", path);  // a reader never sees half a table
}

namespace {

struct Series {
  std::string name;
  std::vector<double> y;
};

// A line chart: x the bucket's start in minutes, one polyline per series
// (points where the value is NaN are left out), axes with their range.
void writeSvg(const std::string& path, const std::string& title, const std::string& unit, const std::vector<double>& x,
              const std::vector<Series>& series) {
  constexpr double W = 720, H = 360, L = 80, R = 170, T = 40, B = 50;
  // Ticks as plain numbers (1980, not 1.98e+03, whose width ran into the axis' label).
  const auto tick = [](double v) { return v >= 100 ? fmt::format("{:.0f}", v) : fmt::format("{:.3g}", v); };
  double ymax = 0, xmax = 0;
  for (double v : x) xmax = std::max(xmax, v);
  for (const auto& s : series)
    for (double v : s.y)
      if (!std::isnan(v)) ymax = std::max(ymax, v);
  if (ymax <= 0) ymax = 1;
  if (xmax <= 0) xmax = 1;
  ymax *= 1.1;
  static const char* colors[] = {"#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#17becf", "#7f7f7f"};
  std::ofstream out(path);
  out << fmt::format("<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{}\" height=\"{}\" font-family=\"sans-serif\" "
                     "font-size=\"12\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n",
                     W, H);
  out << fmt::format("<text x=\"{}\" y=\"22\" font-size=\"15\">{}</text>\n", L, title);
  out << fmt::format("<line x1=\"{0}\" y1=\"{1}\" x2=\"{2}\" y2=\"{1}\" stroke=\"black\"/>\n", L, H - B, W - R);
  out << fmt::format("<line x1=\"{0}\" y1=\"{1}\" x2=\"{0}\" y2=\"{2}\" stroke=\"black\"/>\n", L, T, H - B);
  for (int i = 0; i <= 4; ++i) {
    const double yv = ymax * i / 4, py = H - B - (H - T - B) * i / 4.0;
    out << fmt::format("<text x=\"{}\" y=\"{}\" text-anchor=\"end\">{}</text>\n", L - 6, py + 4, tick(yv));
    out << fmt::format("<line x1=\"{0}\" y1=\"{1}\" x2=\"{2}\" y2=\"{1}\" stroke=\"#ddd\"/>\n", L, py, W - R);
    const double xv = xmax * i / 4, px = L + (W - L - R) * i / 4.0;
    out << fmt::format("<text x=\"{}\" y=\"{}\" text-anchor=\"middle\">{}</text>\n", px, H - B + 18, tick(xv));
  }
  out << fmt::format("<text x=\"{}\" y=\"{}\" text-anchor=\"middle\">minutes of play</text>\n", L + (W - L - R) / 2, H - 10);
  out << fmt::format("<text x=\"14\" y=\"{}\" transform=\"rotate(-90 14 {})\" text-anchor=\"middle\">{}</text>\n",
                     (H - B + T) / 2, (H - B + T) / 2, unit);
  for (size_t k = 0; k < series.size(); ++k) {
    const char* c = colors[k % 8];
    std::string pts;
    for (size_t i = 0; i < x.size() && i < series[k].y.size(); ++i) {
      if (std::isnan(series[k].y[i])) continue;
      pts += fmt::format("{:.1f},{:.1f} ", L + (W - L - R) * x[i] / xmax, H - B - (H - T - B) * series[k].y[i] / ymax);
    }
    out << fmt::format("<polyline class=\"series\" data-name=\"{}\" fill=\"none\" stroke=\"{}\" stroke-width=\"2\" "
                       "points=\"{}\"/>\n",
                       series[k].name, c, pts);
    out << fmt::format("<text x=\"{}\" y=\"{}\" fill=\"{}\">{}</text>\n", W - R + 10, T + 16 * (k + 1), c, series[k].name);
  }
  out << "</svg>\n";
  if (!out) throw Error(path + ": cannot write; check the output folder");
}

// The play's length in buckets: up to the last that had frames (the end of run after it is judged apart).
size_t playedBuckets(const std::vector<Bucket>& b) {
  size_t played = 0;
  for (size_t i = 0; i < b.size(); ++i)
    if (b[i].frames_due > 0 || b[i].frames_posed > 0 || b[i].frames_fused > 0) played = i + 1;
  return played;
}

}  // namespace

std::vector<std::string> writePlots(const std::vector<Bucket>& b, const std::string& dir) {
  std::vector<double> x;
  for (const auto& k : b) x.push_back(k.t0_s / 60.0);
  // A quantity per bucket; the frame counts, latencies and times only while frames played (the end of
  // run after the last one has none, and would draw them falling to 0).
  const size_t played = playedBuckets(b);
  auto col = [&](auto f, bool whole_run = false) {
    std::vector<double> v;
    for (size_t i = 0; i < b.size(); ++i) v.push_back(whole_run || i < played ? f(b[i]) : kNaN);
    return v;
  };
  const std::string frames = dir + "/longrun_frames.svg", latency = dir + "/longrun_latency.svg",
                    times = dir + "/longrun_times.svg", memory = dir + "/longrun_memory.svg";
  writeSvg(frames, "Frames per bucket", "frames",  x,
           {{"due", col([](const Bucket& k) { return k.frames_due; })},
            {"posed", col([](const Bucket& k) { return k.frames_posed; })},
            {"fused", col([](const Bucket& k) { return k.frames_fused; })},
            {"dropped", col([](const Bucket& k) { return k.frames_dropped; })},
            {"skipped", col([](const Bucket& k) { return k.frames_skipped; })}});
  writeSvg(latency, "Capture to pose", "ms", x,
           {{"p50", col([](const Bucket& k) { return k.latency_p50_ms; })},
            {"p95", col([](const Bucket& k) { return k.latency_p95_ms; })}});
  writeSvg(times, "Optimiser solve, correction round, loop check per keyframe, integration", "ms", x,
           {{"solve mean", col([](const Bucket& k) { return k.solve_ms_mean; })},
            {"round mean", col([](const Bucket& k) { return k.round_ms_mean; })},
            {"loop check mean", col([](const Bucket& k) { return k.loop_check_ms_mean; })},
            {"integrate mean", col([](const Bucket& k) { return k.integrate_ms_mean; })},
            // The synth source's rendering of a frame, or the player's wait for a frame's decoding.
            {"source wait mean", col([](const Bucket& k) { return k.render_ms_mean; })}});
  std::vector<Series> mem;
  for (const auto& n : services(b))
    mem.push_back({n, col([&](const Bucket& k) { return k.rss_mb.count(n) ? k.rss_mb.at(n) : kNaN; }, true)});
  for (const char* t : {"active_mb", "host_mb", "on_disk_mb"})
    mem.push_back({std::string("voxels ") + t,
                   col([&](const Bucket& k) { return k.tier_mb.count(t) ? k.tier_mb.at(t) : kNaN; }, true)});
  writeSvg(memory, "Resident memory per service, mapper voxel tiers", "MB", x, mem);
  return {frames, latency, times, memory};
}

namespace {

// Whether a bucket overlaps the window [a, e] seconds (a short run's windows are narrower than a bucket).
bool inWindow(const Bucket& k, double bucket_s, double a, double e) { return k.t0_s < e && k.t0_s + bucket_s > a; }

// The mean of a bucket quantity over the buckets that overlap [a, e] seconds.
double windowMean(const std::vector<Bucket>& b, double bucket_s, double a, double e, double Bucket::*field) {
  std::vector<double> v;
  for (const auto& k : b)
    if (inWindow(k, bucket_s, a, e) && !std::isnan(k.*field)) v.push_back(k.*field);
  return mean(v);
}

GoalLine ratioGoal(const std::string& goal, double last, double ref, double bound) {
  if (std::isnan(last) || std::isnan(ref) || ref <= 0) return {"n/a", goal, "not measured in both windows"};
  const double r = last / ref;
  return {r <= bound ? "PASS" : "FAIL", goal, fmt::format("{:.3g} / {:.3g} = {:.2f}x (bound {:.1f}x)", last, ref, r, bound)};
}

}  // namespace

std::vector<GoalLine> judgeGoals(const std::vector<Bucket>& b, double bucket_s, double end_of_run_s) {
  std::vector<GoalLine> out;
  double due = 0, fused = 0, sent = 0, posed = 0;
  for (const auto& k : b) {
    due += k.frames_due;
    fused += k.frames_fused;
    sent += k.frames_sent;
    posed += k.frames_posed;
  }
  // A dataset's player writes no per-second counts: the frames it played are those posed or fused at most.
  if (due == 0) due = std::max(posed, fused);
  if (due > 0) {
    const double f = fused / due;
    out.push_back({f >= 0.95 ? "PASS" : "FAIL", "at least 95 % of frames fused",
                   fmt::format("{:.1f} % ({:.0f} of {:.0f}; sent {:.0f})", 100 * f, fused, due, sent)});
  } else {
    out.push_back({"n/a", "at least 95 % of frames fused", "no frames"});
  }
  const double d = static_cast<double>(playedBuckets(b)) * bucket_s;
  const double e0 = d / 60, e1 = d / 6, m10 = 9 * d / 60, l0 = 5 * d / 6, s0 = d / 12, s1 = d / 4;
  // A mean over the last window within 1.5x of its mean over [r0, r1].
  auto meanGoal = [&](const std::string& what, double Bucket::*field, double r0, double r1) {
    return ratioGoal(fmt::format("{}, last [{:.0f}, {:.0f}] s within 1.5x of [{:.0f}, {:.0f}] s", what, l0, d, r0, r1),
                     windowMean(b, bucket_s, l0, d, field), windowMean(b, bucket_s, r0, r1, field), 1.5);
  };
  out.push_back(meanGoal("capture-to-pose p95", &Bucket::latency_p95_ms, e0, e1));
  std::vector<std::string> names;
  for (const auto& k : b)
    for (const auto& [n, mb] : k.rss_mb)
      if (std::find(names.begin(), names.end(), n) == names.end()) names.push_back(n);
  for (const auto& n : names) {
    std::vector<double> last, ref;
    for (const auto& k : b) {
      if (!k.rss_mb.count(n)) continue;
      if (inWindow(k, bucket_s, l0, d)) last.push_back(k.rss_mb.at(n));
      if (inWindow(k, bucket_s, m10, e1)) ref.push_back(k.rss_mb.at(n));
    }
    out.push_back(ratioGoal(fmt::format("RSS of {}, last [{:.0f}, {:.0f}] s (peak) within 1.2x of [{:.0f}, {:.0f}] s", n, l0, d, m10, e1),
                            maxOf(last), maxOf(ref), 1.2));
  }
  double peak_total = 0;
  for (const auto& k : b) {
    double total = 0;
    for (const auto& [n, mb] : k.rss_mb) total += mb;
    peak_total = std::max(peak_total, total);
  }
  out.push_back(names.empty() ? GoalLine{"n/a", "all services together at most 2500 MB", "no RSS samples"}
                              : GoalLine{peak_total <= 2500 ? "PASS" : "FAIL", "all services together at most 2500 MB",
                                         fmt::format("peak {:.0f} MB", peak_total)});
  out.push_back(meanGoal("optimiser solve time", &Bucket::solve_ms_mean, s0, s1));
  out.push_back(meanGoal("loop-check time per keyframe", &Bucket::loop_check_ms_mean, s0, s1));
  out.push_back(meanGoal("correction round time", &Bucket::round_ms_mean, s0, s1));
  out.push_back(end_of_run_s < 0 ? GoalLine{"n/a", "end of run (final pass and meshes) within 180 s", "the run did not end"}
                                 : GoalLine{end_of_run_s <= 180 ? "PASS" : "FAIL", "end of run (final pass and meshes) within 180 s",
                                            fmt::format("{:.1f} s", end_of_run_s)});
  out.push_back({"n/a", "ATE and CORR/COMPL no worse than a 10-minute scan of the same space",
                 "score it with rekon eval traj and rekon eval surface against groundtruth.txt and mesh_gt.ply (a --scene run "
                 "writes them into OUT; a rekon synth dataset holds them)"});
  return out;
}

void writeSummary(const std::vector<GoalLine>& lines, const std::string& header, const std::string& path) {
  std::ofstream out(path);
  out << header << "\n";
  for (const auto& l : lines) out << fmt::format("{:<4}  {}: {}\n", l.verdict, l.goal, l.measured);
  if (!out) throw Error(path + ": cannot write; check the output folder");
}

}  // namespace rekon::longrun
