#pragma once
// SVG line plots for run reports and the paper's figures: several series,
// linear or logarithmic axes, ticks, axis labels and a legend. Every saved
// plot has its data next to it as CSV, so a figure can be re-plotted or
// checked without parsing SVG.
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace rekon::report {

enum class Scale { Linear, Log };

struct Series {
  Series() = default;
  Series(std::string name_, std::vector<double> x_, std::vector<double> y_)
      : name(std::move(name_)), x(std::move(x_)), y(std::move(y_)) {}

  std::string name;  // shown in the legend; empty = not listed
  std::vector<double> x, y;
  bool line = true;      // a polyline through the points
  bool markers = false;  // a dot on every point
  bool dashed = false;
  std::string color;  // any SVG color; empty = the palette entry of the series' index
};

struct PlotOptions {
  static constexpr int kDefaultWidth = 720;
  static constexpr int kDefaultHeight = 420;
  std::string title, x_label, y_label;
  Scale x_scale = Scale::Linear;
  Scale y_scale = Scale::Linear;
  int width = kDefaultWidth;
  int height = kDefaultHeight;
  // One metre is as long on both axes (trajectories); linear axes only.
  bool equal_aspect = false;
  // The automatic y range reaches down (or up) to 0, for amounts such as times and counts; linear axes only.
  bool y_includes_zero = false;
  // Fixed axis ranges; empty = a range with round ends around all the data.
  std::optional<std::pair<double, double>> x_range, y_range;
};

struct Tick {
  double value = 0.0;
  std::string label;
};

// The extent of one axis and its labelled ticks.
struct AxisLayout {
  double lo = 0.0, hi = 1.0;
  Scale scale = Scale::Linear;
  std::vector<Tick> ticks;
};

// An axis around data in [data_lo, data_hi] with round ends: multiples of a
// 1-2-5 step on a linear axis (about 5 ticks), whole decades on a log axis
// (a tick per decade, plus 2 and 5 when the data spans under two decades).
// A log axis needs data_lo > 0; throws rekon::Error otherwise.
AxisLayout layoutAxis(double data_lo, double data_hi, Scale scale);
// The ticks of a given range (for ranges widened by equal_aspect or fixed by the caller).
std::vector<Tick> ticksWithin(double lo, double hi, Scale scale);

class LinePlot {
 public:
  explicit LinePlot(PlotOptions options) : options_(std::move(options)) {}
  // Throws rekon::Error when x and y differ in length.
  LinePlot& add(Series series);

  const PlotOptions& options() const { return options_; }
  const std::vector<Series>& series() const { return series_; }

  // The standalone SVG document. The legend sits in the corner of the plot
  // area that covers the fewest data points and lines. Points that cannot be drawn (non-finite, not
  // positive on a log axis, outside a fixed range) break the line there.
  std::string svg() const;
  // Long format, one row per point: `series,x,y`.
  std::string csv() const;
  // Writes the SVG to `svg_path` and the CSV next to it (same name, .csv).
  void save(const std::string& svg_path) const;

 private:
  PlotOptions options_;
  std::vector<Series> series_;
};

// The default color of series number `index` (a colour-blind-safe palette, repeating).
std::string paletteColor(size_t index);

}  // namespace rekon::report
