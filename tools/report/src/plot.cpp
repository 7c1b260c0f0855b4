#include "rekon/report/plot.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "rekon/common/error.hpp"
#include "svg_text.hpp"

namespace rekon::report {
namespace {

// Plot area margins in pixels: room for tick labels, axis labels and the title.
constexpr double kMarginLeft = 78, kMarginRight = 18, kMarginTop = 34, kMarginBottom = 52;
constexpr double kTargetLinearTicks = 5.0;
// Beyond this many decades only every n-th decade is labelled.
constexpr int kMaxLogTicks = 8;
constexpr double kRelativeEpsilon = 1e-9;
// Spacing of the points sampled along lines when choosing where the legend hides least.
constexpr double kLegendSamplePixels = 4.0;

// Okabe-Ito, the colour-blind-safe palette, without its yellow (too light on white).
const char* const kPalette[] = {"#0072B2", "#D55E00", "#009E73", "#CC79A7", "#56B4E9", "#E69F00", "#000000"};

double niceStep(double span) {
  const double raw = span / kTargetLinearTicks;
  const double magnitude = std::pow(10.0, std::floor(std::log10(raw)));
  const double f = raw / magnitude;
  return (f < 1.5 ? 1.0 : f < 3.5 ? 2.0 : f < 7.5 ? 5.0 : 10.0) * magnitude;
}

std::string linearLabel(double v, double step) {
  const int decimals = std::max(0, static_cast<int>(-std::floor(std::log10(step) + kRelativeEpsilon)));
  if (std::abs(v) < step * kRelativeEpsilon) v = 0.0;  // no "-0"
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
  return buf;
}

std::string logLabel(double v) {
  const double e = std::log10(v);
  char buf[64];
  if (e >= -3.0 - kRelativeEpsilon && e <= 5.0 + kRelativeEpsilon) std::snprintf(buf, sizeof buf, "%g", v);
  else std::snprintf(buf, sizeof buf, "%.0e", v);
  return buf;
}

struct Frame {  // data-to-pixel mapping of the plot area
  AxisLayout x, y;
  double left, right, top, bottom;

  static double t(double v, const AxisLayout& a) {
    if (a.scale == Scale::Log) return (std::log10(v) - std::log10(a.lo)) / (std::log10(a.hi) - std::log10(a.lo));
    return (v - a.lo) / (a.hi - a.lo);
  }
  static bool inside(double v, const AxisLayout& a) {
    if (!std::isfinite(v) || (a.scale == Scale::Log && v <= 0)) return false;
    const double tol = (a.hi - a.lo) * kRelativeEpsilon;
    return v >= a.lo - tol && v <= a.hi + tol;
  }
  bool drawable(double vx, double vy) const { return inside(vx, x) && inside(vy, y); }
  double px(double v) const { return left + t(v, x) * (right - left); }
  double py(double v) const { return bottom - t(v, y) * (bottom - top); }
};

std::pair<double, double> dataExtent(const std::vector<Series>& series, bool use_x, Scale scale) {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const auto& s : series) {
    for (double v : use_x ? s.x : s.y) {
      if (!std::isfinite(v) || (scale == Scale::Log && v <= 0)) continue;
      lo = std::min(lo, v);
      hi = std::max(hi, v);
    }
  }
  if (lo > hi) return scale == Scale::Log ? std::pair{1.0, 10.0} : std::pair{0.0, 1.0};  // no data: an empty frame
  return {lo, hi};
}

AxisLayout axisFor(const std::optional<std::pair<double, double>>& fixed, std::pair<double, double> extent, Scale scale) {
  if (!fixed) return layoutAxis(extent.first, extent.second, scale);
  if (!(fixed->first < fixed->second) || (scale == Scale::Log && fixed->first <= 0)) {
    throw Error("plot range [" + std::to_string(fixed->first) + ", " + std::to_string(fixed->second) +
                "] is empty or not positive on a log axis; give lo < hi (and lo > 0 for log)");
  }
  return {fixed->first, fixed->second, scale, ticksWithin(fixed->first, fixed->second, scale)};
}

// Widens the axis with fewer units per pixel so that both have the same.
void equaliseAspect(Frame& f) {
  const double ux = (f.x.hi - f.x.lo) / (f.right - f.left), uy = (f.y.hi - f.y.lo) / (f.bottom - f.top);
  AxisLayout& a = ux < uy ? f.x : f.y;
  const double pixels = ux < uy ? f.right - f.left : f.bottom - f.top;
  const double want = std::max(ux, uy) * pixels, centre = 0.5 * (a.lo + a.hi);
  a.lo = centre - 0.5 * want;
  a.hi = centre + 0.5 * want;
  a.ticks = ticksWithin(a.lo, a.hi, Scale::Linear);
}

std::string fmt(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1f", v);
  return buf;
}

void drawAxes(std::ostringstream& o, const Frame& f, const PlotOptions& opt) {
  o << "<rect x=\"" << fmt(f.left) << "\" y=\"" << fmt(f.top) << "\" width=\"" << fmt(f.right - f.left) << "\" height=\""
    << fmt(f.bottom - f.top) << "\" fill=\"white\" stroke=\"#444\"/>\n";
  for (const auto& t : f.x.ticks) {
    const double x = f.px(t.value);
    o << "<line x1=\"" << fmt(x) << "\" y1=\"" << fmt(f.top) << "\" x2=\"" << fmt(x) << "\" y2=\"" << fmt(f.bottom)
      << "\" stroke=\"#ddd\"/>\n";
    o << "<text class=\"tick-x\" x=\"" << fmt(x) << "\" y=\"" << fmt(f.bottom + 16) << "\" text-anchor=\"middle\">"
      << escapeXml(t.label) << "</text>\n";
  }
  for (const auto& t : f.y.ticks) {
    const double y = f.py(t.value);
    o << "<line x1=\"" << fmt(f.left) << "\" y1=\"" << fmt(y) << "\" x2=\"" << fmt(f.right) << "\" y2=\"" << fmt(y)
      << "\" stroke=\"#ddd\"/>\n";
    o << "<text class=\"tick-y\" x=\"" << fmt(f.left - 6) << "\" y=\"" << fmt(y + 4) << "\" text-anchor=\"end\">"
      << escapeXml(t.label) << "</text>\n";
  }
  o << "<text x=\"" << fmt(0.5 * (f.left + f.right)) << "\" y=\"" << fmt(f.bottom + 40)
    << "\" text-anchor=\"middle\">" << escapeXml(opt.x_label) << "</text>\n";
  o << "<text x=\"16\" y=\"" << fmt(0.5 * (f.top + f.bottom)) << "\" text-anchor=\"middle\" transform=\"rotate(-90 16 "
    << fmt(0.5 * (f.top + f.bottom)) << ")\">" << escapeXml(opt.y_label) << "</text>\n";
  if (!opt.title.empty()) {
    o << "<text x=\"" << fmt(0.5 * opt.width) << "\" y=\"20\" text-anchor=\"middle\" font-weight=\"bold\">"
      << escapeXml(opt.title) << "</text>\n";
  }
}

void drawSeries(std::ostringstream& o, const Frame& f, const Series& s, const std::string& color) {
  const std::string dash = s.dashed ? " stroke-dasharray=\"6 4\"" : "";
  std::string points;
  size_t count = 0;
  const auto flush = [&] {
    if (count >= 2 && s.line) {
      o << "<polyline class=\"series\" fill=\"none\" stroke=\"" << color << "\" stroke-width=\"1.6\"" << dash
        << " points=\"" << points << "\"/>\n";
    }
    points.clear();
    count = 0;
  };
  for (size_t i = 0; i < s.x.size(); ++i) {
    if (!f.drawable(s.x[i], s.y[i])) {
      flush();
      continue;
    }
    const double x = f.px(s.x[i]), y = f.py(s.y[i]);
    if (count) points += ' ';
    points += fmt(x);
    points += ',';
    points += fmt(y);
    ++count;
    if (s.markers) o << "<circle cx=\"" << fmt(x) << "\" cy=\"" << fmt(y) << "\" r=\"3\" fill=\"" << color << "\"/>\n";
  }
  flush();
}

void drawLegend(std::ostringstream& o, const Frame& f, const std::vector<Series>& series) {
  std::vector<size_t> listed;
  size_t longest = 0;
  for (size_t i = 0; i < series.size(); ++i) {
    if (series[i].name.empty()) continue;
    listed.push_back(i);
    longest = std::max(longest, series[i].name.size());
  }
  if (listed.empty()) return;
  constexpr double kRow = 16, kCharWidth = 6.6, kSwatch = 22;
  const double w = kSwatch + 14 + kCharWidth * static_cast<double>(longest), h = kRow * static_cast<double>(listed.size()) + 8;
  // The corner that hides the least of the data: top right, top left, bottom right, bottom left, first wins a tie.
  constexpr double kInset = 8;
  const double corners[4][2] = {{f.right - w - kInset, f.top + kInset}, {f.left + kInset, f.top + kInset},
                                {f.right - w - kInset, f.bottom - h - kInset}, {f.left + kInset, f.bottom - h - kInset}};
  size_t hidden[4] = {0, 0, 0, 0};
  for (const Series& s : series) {
    for (size_t i = 0; i < s.x.size(); ++i) {
      if (!f.drawable(s.x[i], s.y[i])) continue;
      const double px = f.px(s.x[i]), py = f.py(s.y[i]);
      const bool joined = s.line && i + 1 < s.x.size() && f.drawable(s.x[i + 1], s.y[i + 1]);
      const double length = joined ? std::hypot(f.px(s.x[i + 1]) - px, f.py(s.y[i + 1]) - py) : 0.0;
      const int samples = 1 + static_cast<int>(length / kLegendSamplePixels);  // points along the line to the next point
      for (int k = 0; k < samples; ++k) {
        const double t = static_cast<double>(k) / samples;
        const double qx = joined ? px + t * (f.px(s.x[i + 1]) - px) : px, qy = joined ? py + t * (f.py(s.y[i + 1]) - py) : py;
        for (int c = 0; c < 4; ++c) {
          hidden[c] += qx >= corners[c][0] && qx <= corners[c][0] + w && qy >= corners[c][1] && qy <= corners[c][1] + h;
        }
      }
    }
  }
  const size_t best = static_cast<size_t>(std::min_element(hidden, hidden + 4) - hidden);
  const double x0 = corners[best][0], y0 = corners[best][1];
  o << "<g class=\"legend\"><rect x=\"" << fmt(x0) << "\" y=\"" << fmt(y0) << "\" width=\"" << fmt(w) << "\" height=\""
    << fmt(h) << "\" fill=\"white\" fill-opacity=\"0.85\" stroke=\"#999\"/>\n";
  for (size_t r = 0; r < listed.size(); ++r) {
    const Series& s = series[listed[r]];
    const std::string color = s.color.empty() ? paletteColor(listed[r]) : s.color;
    const double y = y0 + 4 + kRow * (static_cast<double>(r) + 0.5);
    if (s.line) {
      o << "<line x1=\"" << fmt(x0 + 6) << "\" y1=\"" << fmt(y) << "\" x2=\"" << fmt(x0 + 6 + kSwatch) << "\" y2=\"" << fmt(y)
        << "\" stroke=\"" << color << "\" stroke-width=\"2\"" << (s.dashed ? " stroke-dasharray=\"6 4\"" : "") << "/>";
    }
    if (s.markers) o << "<circle cx=\"" << fmt(x0 + 6 + kSwatch / 2) << "\" cy=\"" << fmt(y) << "\" r=\"3\" fill=\"" << color << "\"/>";
    o << "<text x=\"" << fmt(x0 + kSwatch + 12) << "\" y=\"" << fmt(y + 4) << "\">" << escapeXml(s.name) << "</text>\n";
  }
  o << "</g>\n";
}

std::string csvField(const std::string& s) {
  if (s.find_first_of(",\"\n") == std::string::npos) return s;
  std::string q = "\"";
  for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c);
  return q + "\"";
}

std::vector<Tick> linearTicks(double lo, double hi, double step) {
  std::vector<Tick> ticks;
  for (double k = std::ceil(lo / step - kRelativeEpsilon); k * step <= hi + step * kRelativeEpsilon; k += 1.0) {
    ticks.push_back({k * step, linearLabel(k * step, step)});
  }
  return ticks;
}

}  // namespace

std::string paletteColor(size_t index) { return kPalette[index % std::size(kPalette)]; }

std::vector<Tick> ticksWithin(double lo, double hi, Scale scale) {
  std::vector<Tick> ticks;
  if (!(lo < hi)) return ticks;
  if (scale == Scale::Linear) return linearTicks(lo, hi, niceStep(hi - lo));
  const int first = static_cast<int>(std::ceil(std::log10(lo) - kRelativeEpsilon));
  const int last = static_cast<int>(std::floor(std::log10(hi) + kRelativeEpsilon));
  const int decades = last - first + 1;
  const int every = std::max(1, (decades + kMaxLogTicks - 1) / kMaxLogTicks);
  for (int e = first; e <= last; e += every) ticks.push_back({std::pow(10.0, e), logLabel(std::pow(10.0, e))});
  if (decades < 3) {  // a short span: 2 and 5 in each decade too, or the axis has two labels at most
    for (int e = first - 1; e <= last; ++e) {
      for (double m : {2.0, 5.0}) {
        const double v = m * std::pow(10.0, e);
        if (v >= lo * (1 - kRelativeEpsilon) && v <= hi * (1 + kRelativeEpsilon)) ticks.push_back({v, logLabel(v)});
      }
    }
    std::sort(ticks.begin(), ticks.end(), [](const Tick& a, const Tick& b) { return a.value < b.value; });
  }
  return ticks;
}

AxisLayout layoutAxis(double data_lo, double data_hi, Scale scale) {
  if (!std::isfinite(data_lo) || !std::isfinite(data_hi) || data_lo > data_hi) {
    throw Error("plot axis data range [" + std::to_string(data_lo) + ", " + std::to_string(data_hi) + "] is not a range");
  }
  AxisLayout a;
  a.scale = scale;
  if (scale == Scale::Log) {
    if (data_lo <= 0) throw Error("a log axis needs positive values, got " + std::to_string(data_lo) + "; use a linear axis");
    a.lo = std::pow(10.0, std::floor(std::log10(data_lo) + kRelativeEpsilon));
    a.hi = std::pow(10.0, std::ceil(std::log10(data_hi) - kRelativeEpsilon));
    if (a.hi <= a.lo) a.hi = a.lo * 10.0;
  } else {
    if (data_hi - data_lo <= std::abs(data_hi) * kRelativeEpsilon) {  // one value: a range around it
      const double pad = data_lo == 0 ? 1.0 : 0.1 * std::abs(data_lo);
      data_lo -= pad;
      data_hi += pad;
    }
    const double step = niceStep(data_hi - data_lo);
    a.lo = std::floor(data_lo / step + kRelativeEpsilon) * step;
    a.hi = std::ceil(data_hi / step - kRelativeEpsilon) * step;
    a.ticks = linearTicks(a.lo, a.hi, step);  // the step of the ends, not one chosen anew for the rounded span
    return a;
  }
  a.ticks = ticksWithin(a.lo, a.hi, scale);
  return a;
}

LinePlot& LinePlot::add(Series series) {
  if (series.x.size() != series.y.size()) {
    throw Error("plot series '" + series.name + "' has " + std::to_string(series.x.size()) + " x values but " +
                std::to_string(series.y.size()) + " y values; give one y per x");
  }
  series_.push_back(std::move(series));
  return *this;
}

std::string LinePlot::svg() const {
  const PlotOptions& opt = options_;
  if (opt.equal_aspect && (opt.x_scale == Scale::Log || opt.y_scale == Scale::Log)) {
    throw Error("plot '" + opt.title + "': equal_aspect needs linear axes");
  }
  auto y_extent = dataExtent(series_, false, opt.y_scale);
  if (opt.y_includes_zero && opt.y_scale == Scale::Linear) {
    y_extent = {std::min(y_extent.first, 0.0), std::max(y_extent.second, 0.0)};
  }
  Frame f{axisFor(opt.x_range, dataExtent(series_, true, opt.x_scale), opt.x_scale),
          axisFor(opt.y_range, y_extent, opt.y_scale),
          kMarginLeft, opt.width - kMarginRight, kMarginTop, opt.height - kMarginBottom};
  if (opt.equal_aspect) equaliseAspect(f);
  std::ostringstream o;
  o << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << opt.width << "\" height=\"" << opt.height
    << "\" viewBox=\"0 0 " << opt.width << " " << opt.height << "\" font-family=\"sans-serif\" font-size=\"12\">\n";
  o << "<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  drawAxes(o, f, opt);
  for (size_t i = 0; i < series_.size(); ++i) {
    drawSeries(o, f, series_[i], series_[i].color.empty() ? paletteColor(i) : series_[i].color);
  }
  drawLegend(o, f, series_);
  o << "</svg>\n";
  return o.str();
}

std::string LinePlot::csv() const {
  std::ostringstream o;
  o.precision(9);
  o << "series,x,y\n";
  for (const auto& s : series_) {
    for (size_t i = 0; i < s.x.size(); ++i) o << csvField(s.name) << "," << s.x[i] << "," << s.y[i] << "\n";
  }
  return o.str();
}

void LinePlot::save(const std::string& svg_path) const {
  const std::filesystem::path path(svg_path);
  if (path.has_parent_path()) std::filesystem::create_directories(path.parent_path());
  const auto write = [](const std::filesystem::path& p, const std::string& text) {
    std::ofstream f(p);
    f << text;
    if (!f) throw Error(p.string() + ": cannot write the plot; check that the folder is writable");
  };
  write(path, svg());
  write(std::filesystem::path(path).replace_extension(".csv"), csv());
}

}  // namespace rekon::report
