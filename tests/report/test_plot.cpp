// SVG line plots and trajectory plots: axes, ticks, points, CSV next to the SVG.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>

#include "rekon/common/error.hpp"
#include "rekon/report/html.hpp"
#include "rekon/report/plot.hpp"
#include "rekon/report/trajectory_plot.hpp"
#include "test_support.hpp"

namespace {

using namespace rekon::report;

size_t countOf(const std::string& text, const std::string& what) {
  size_t n = 0;
  for (size_t p = text.find(what); p != std::string::npos; p = text.find(what, p + what.size())) ++n;
  return n;
}

// The point lists of every polyline, as (x, y) pixel pairs.
std::vector<std::vector<std::pair<double, double>>> polylines(const std::string& svg) {
  std::vector<std::vector<std::pair<double, double>>> out;
  const std::regex re("<polyline[^>]* points=\"([^\"]*)\"");
  for (auto it = std::sregex_iterator(svg.begin(), svg.end(), re); it != std::sregex_iterator(); ++it) {
    std::istringstream in((*it)[1].str());
    std::vector<std::pair<double, double>> points;
    std::string pair;
    while (in >> pair) {
      const size_t comma = pair.find(',');
      points.emplace_back(std::stod(pair.substr(0, comma)), std::stod(pair.substr(comma + 1)));
    }
    out.push_back(points);
  }
  return out;
}

std::vector<double> values(const std::vector<Tick>& ticks) {
  std::vector<double> v;
  for (const auto& t : ticks) v.push_back(t.value);
  return v;
}

TEST(PlotAxis, LogAxisHasOneTickPerDecadeBetweenWholeDecades) {
  const AxisLayout a = layoutAxis(1.5, 800, Scale::Log);
  EXPECT_DOUBLE_EQ(a.lo, 1.0);  // rounded down to the decade below
  EXPECT_DOUBLE_EQ(a.hi, 1000.0);
  ASSERT_EQ(a.ticks.size(), 4u);  // 1, 10, 100, 1000
  EXPECT_EQ(a.ticks[0].label, "1");
  EXPECT_EQ(a.ticks[3].label, "1000");
}

TEST(PlotAxis, ShortLogAxisAlsoMarksTwoAndFive) {
  // 2..8 lies in one decade: 1, 2, 5, 10, or the axis would carry just two labels.
  EXPECT_EQ(values(layoutAxis(2, 8, Scale::Log).ticks), (std::vector<double>{1, 2, 5, 10}));
}

TEST(PlotAxis, LinearAxisEndsOnMultiplesOfAOneTwoFiveStep) {
  const AxisLayout a = layoutAxis(0.3, 9.2, Scale::Linear);
  // span 8.9 / 5 target ticks = 1.78, rounded to the 1-2-5 step 2.
  EXPECT_EQ(values(a.ticks), (std::vector<double>{0, 2, 4, 6, 8, 10}));
  // 0.01..0.049: step 0.01, so two decimals and no rounding noise.
  EXPECT_EQ(layoutAxis(0.01, 0.049, Scale::Linear).ticks[1].label, "0.02");
}

TEST(PlotAxis, LogAxisOfNonPositiveDataIsAnError) {
  EXPECT_THROW(layoutAxis(0.0, 10.0, Scale::Log), rekon::Error);
}

LinePlot logLogPlot() {
  PlotOptions o;
  o.title = "CORR against kappa";
  o.x_label = "average keyframe size";
  o.y_label = "CORR [mm]";
  o.x_scale = o.y_scale = Scale::Log;
  LinePlot p(o);
  Series constant("KF_CONST", {1, 10, 100, 1000}, {0.5, 2, 8, 40});
  constant.markers = true;
  p.add(constant);
  p.add({"KF_DIST", {2, 20, 200}, {0.6, 3, 9}});
  return p;
}

TEST(LinePlot, SvgHasOnePolylinePointPerDataPoint) {
  const auto lines = polylines(logLogPlot().svg());
  ASSERT_EQ(lines.size(), 2u);
  EXPECT_EQ(lines[0].size(), 4u);
  EXPECT_EQ(lines[1].size(), 3u);
}

TEST(LinePlot, LogLogSvgTicksEveryDecade) {
  const std::string svg = logLogPlot().svg();
  EXPECT_EQ(countOf(svg, "class=\"tick-x\""), 4u);  // x 1..1000: 1, 10, 100, 1000
  EXPECT_EQ(countOf(svg, "class=\"tick-y\""), 4u);  // y 0.5..40 -> 0.1..100: 0.1, 1, 10, 100
  EXPECT_NE(svg.find(">0.1</text>"), std::string::npos);
}

TEST(LinePlot, DecadesAreEquallySpacedOnALogAxis) {
  const auto line = polylines(logLogPlot().svg())[0];
  const double d1 = line[1].first - line[0].first, d2 = line[2].first - line[1].first;
  EXPECT_GT(d1, 100.0);
  EXPECT_NEAR(d1, d2, 0.15);  // pixels, rounded to 0.1 in the SVG
}

TEST(LinePlot, SvgHasLegendWithEveryNamedSeriesAndTheLabels) {
  const std::string svg = logLogPlot().svg();
  EXPECT_NE(svg.find(">KF_CONST</text>"), std::string::npos);
  EXPECT_NE(svg.find(">KF_DIST</text>"), std::string::npos);
  EXPECT_NE(svg.find(">average keyframe size</text>"), std::string::npos);
  EXPECT_NE(svg.find(">CORR [mm]</text>"), std::string::npos);
  EXPECT_EQ(countOf(svg, "<circle"), 4u + 1u);  // markers of KF_CONST and its legend entry
}

double legendX(const std::string& svg) {
  const std::regex re("<g class=\"legend\"><rect x=\"([0-9.]+)\" y=\"([0-9.]+)\"");
  std::smatch m;
  EXPECT_TRUE(std::regex_search(svg, m, re)) << "no legend";
  return std::stod(m[1].str());
}

TEST(LinePlot, LegendTakesTheCornerThatHidesNoData) {
  PlotOptions o;  // 720 px wide: the plot area's centre is at x = 78 + (720 - 78 - 18) / 2 = 390
  LinePlot rising(o), falling(o);
  rising.add({"rising", {0, 10}, {0, 10}});  // through the bottom-left and top-right corners
  falling.add({"falling", {0, 10}, {10, 0}});  // through top-left and bottom-right
  EXPECT_LT(legendX(rising.svg()), 390.0);   // top left
  EXPECT_GT(legendX(falling.svg()), 390.0);  // top right
}

TEST(LinePlot, PointThatALogAxisCannotShowBreaksTheLine) {
  PlotOptions o;
  o.y_scale = Scale::Log;
  LinePlot p(o);
  p.add({"s", {0, 1, 2, 3, 4}, {1, 2, 0, 4, 8}});  // y = 0 has no place on a log axis
  const auto lines = polylines(p.svg());
  ASSERT_EQ(lines.size(), 2u);
  EXPECT_EQ(lines[0].size(), 2u);
  EXPECT_EQ(lines[1].size(), 2u);
}

TEST(LinePlot, NanBreaksTheLine) {
  LinePlot p(PlotOptions{});
  p.add({"s", {0, 1, 2, 3, 4, 5}, {1, 2, NAN, 4, 8, 9}});
  const auto lines = polylines(p.svg());
  ASSERT_EQ(lines.size(), 2u);
  EXPECT_EQ(lines[1].size(), 3u);
}

TEST(LinePlot, AmountsCanBePlottedFromZero) {
  for (bool from_zero : {false, true}) {
    PlotOptions o;
    o.y_includes_zero = from_zero;
    LinePlot p(o);
    p.add({"ms", {0, 1, 2}, {4.2, 5.9, 5.1}});
    // 0..5.9 has step 1: 0, 1, ..., 6; 4.2..5.9 has step 0.2: 4.2, 4.4, ..., 6.0.
    EXPECT_EQ(countOf(p.svg(), "class=\"tick-y\""), from_zero ? 7u : 10u);
    EXPECT_EQ(countOf(p.svg(), ">0</text>"), from_zero ? 1u : 0u);  // x is labelled 0.0, 0.5, ...
  }
}

TEST(LinePlot, SeriesOfUnequalLengthsIsAnError) {
  LinePlot p(PlotOptions{});
  EXPECT_THROW(p.add({"s", {0, 1, 2}, {1, 2}}), rekon::Error);
}

TEST(LinePlot, SaveWritesTheCsvNextToTheSvg) {
  rekon::test::TempDir dir;
  logLogPlot().save(dir / "fig5/corr.svg");
  ASSERT_TRUE(std::filesystem::exists(dir / "fig5/corr.svg"));
  std::ifstream csv(dir / "fig5/corr.csv");
  std::vector<std::string> lines;
  for (std::string l; std::getline(csv, l);) lines.push_back(l);
  ASSERT_EQ(lines.size(), 1u + 4u + 3u);  // header and every point of both series
  EXPECT_EQ(lines[0], "series,x,y");
  EXPECT_EQ(lines[1], "KF_CONST,1,0.5");
  EXPECT_EQ(lines[7], "KF_DIST,200,9");
}

rekon::Trajectory path(const std::vector<Eigen::Vector3d>& points) {
  rekon::Trajectory t;
  for (size_t i = 0; i < points.size(); ++i) {
    rekon::StampedPose p;
    p.timestamp = static_cast<double>(i) / 30.0;
    p.pose.translation() = points[i];
    t.push_back(p);
  }
  return t;
}

TEST(TrajectoryPlot, TopViewUsesTheTwoAxesOfMostExtent) {
  const auto t = path({{0, 5, 0}, {4, 5, 0.1}, {4, 5.2, 2}, {0, 5.2, 2}});  // moves in x and z, hardly in y
  EXPECT_EQ(topViewAxes(t, TopView::MostExtent), std::make_pair(0, 2));
  EXPECT_EQ(topViewAxes(t, TopView::XY), std::make_pair(0, 1));
}

TEST(TrajectoryPlot, OneMetreIsAsLongOnBothAxes) {
  // A 4 m x 1 m rectangle: the plot area is wider than tall, and y must not stretch.
  const auto t = path({{0, 0, 0}, {4, 0, 0}, {4, 1, 0}, {0, 1, 0}});
  const auto line = polylines(trajectoryPlot({{"ground truth", t}}, TopView::XY, "top").svg())[0];
  ASSERT_EQ(line.size(), 4u);
  const double metre_x = (line[1].first - line[0].first) / 4.0, metre_y = line[1].second - line[2].second;
  EXPECT_GT(metre_x, 50.0);
  EXPECT_NEAR(metre_x, metre_y, 0.3);  // SVG coordinates are rounded to 0.1 px
}

TEST(Html, Base64MatchesRfc4648) {
  EXPECT_EQ(base64Encode("Man"), "TWFu");
  EXPECT_EQ(base64Encode("Ma"), "TWE=");
  EXPECT_EQ(base64Encode("M"), "TQ==");
  EXPECT_EQ(base64Encode(""), "");
  EXPECT_EQ(base64Encode("foobar"), "Zm9vYmFy");
}

}  // namespace
