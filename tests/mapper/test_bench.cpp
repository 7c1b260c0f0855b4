// rekon bench keyframes / reintegration (services/mapper/bench) on a few
// frames of the synthetic tabletop: the shape of the outputs, not the numbers.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <regex>
#include <sstream>

#include "rekon/synth/synth.hpp"
#include "test_support.hpp"

namespace {

using rekon::test::runCommand;
namespace fs = std::filesystem;

constexpr int kFrames = 12;

std::string dataset(const rekon::test::TempDir& dir) {
  rekon::synth::SequenceOptions o;
  o.scene = "tabletop";
  o.frames = kFrames;
  o.drift_translation_per_m = 0.05;
  o.drift_rotation_deg_per_m = 3.0;
  rekon::synth::writeSequence(o, dir / "data");
  return dir / "data";
}

// The rows of a CSV with a header as column -> text maps.
std::vector<std::map<std::string, std::string>> readRows(const std::string& path) {
  std::ifstream in(path);
  std::vector<std::string> header;
  std::vector<std::map<std::string, std::string>> rows;
  for (std::string line; std::getline(in, line);) {
    std::vector<std::string> fields;
    std::stringstream s(line);
    for (std::string f; std::getline(s, f, ',');) fields.push_back(f);
    if (header.empty()) {
      header = fields;
      continue;
    }
    std::map<std::string, std::string> row;
    for (size_t i = 0; i < fields.size() && i < header.size(); ++i) row[header[i]] = fields[i];
    rows.push_back(row);
  }
  return rows;
}

std::string lastLine(const std::string& text) {
  std::istringstream in(text);
  std::string last;
  for (std::string line; std::getline(in, line);)
    if (!line.empty()) last = line;
  return last;
}

std::string rekonBin() { return rekon::test::binDir() + "/rekon"; }

}  // namespace

TEST(BenchKeyframes, CsvHasOneRowPerStrategyAndParameterWithKappaBarFromTheKeyframes) {
  rekon::test::TempDir dir;
  const std::string data = dataset(dir);
  std::string out;
  ASSERT_EQ(runCommand(rekonBin() + " bench keyframes --dataset " + data + " --out " + (dir / "out") +
                           " --kappas 1,4 --dist 0.05:5 --overlaps 0.8 --set log.level=warn",
                       &out),
            0)
      << out;
  const auto rows = readRows(dir / "out/keyframes.csv");
  ASSERT_EQ(rows.size(), 5u);  // const kappa 1 and 4, dvo, one dist, one overlap
  EXPECT_EQ(rows[0].at("strategy") + " " + rows[0].at("parameter"), "const kappa=1");
  EXPECT_EQ(rows[1].at("kf_keyframes"), "3");  // 12 frames / kappa 4
  for (const auto& r : rows) {
    EXPECT_EQ(r.at("frames"), std::to_string(kFrames));  // every frame has a ground-truth pose
    const double keyframes = std::stod(r.at("kf_keyframes")), kappa_bar = std::stod(r.at("kappa_bar"));
    EXPECT_NEAR(kappa_bar * keyframes, kFrames, 1e-3) << r.at("strategy");  // kappa-bar = frames / keyframes
    EXPECT_GT(std::stod(r.at("compl_mm")), 0.0);
  }
  EXPECT_EQ(rows[0].at("kappa_bar"), "1.0000");
  EXPECT_TRUE(fs::exists(dir / "out/keyframes_corr.svg"));
  EXPECT_TRUE(fs::exists(dir / "out/keyframes_compl.svg"));
  EXPECT_NE(lastLine(out).find("compl_20_over_1="), std::string::npos) << out;
}

TEST(BenchReintegration, LastLineIsTheTwoRatiosAndTheCsvHasBothModesPerKappa) {
  rekon::test::TempDir dir;
  const std::string data = dataset(dir);
  std::string out;
  ASSERT_EQ(runCommand(rekonBin() + " bench reintegration --dataset " + data + " --out " + (dir / "out") +
                           " --kappas 4 --set log.level=warn 2>/dev/null",
                       &out),
            0)
      << out;
  std::smatch m;
  const std::string last = lastLine(out);
  ASSERT_TRUE(std::regex_match(last, m, std::regex(R"(ours_over_bundlefusion=(\S+) consecutive_over_most_moved=(\S+))")))
      << last;
  for (int i : {1, 2}) {
    const double ratio = std::stod(m[i].str());
    EXPECT_TRUE(std::isfinite(ratio) && ratio > 0) << m[i].str();
  }
  const auto rows = readRows(dir / "out/reintegration.csv");
  ASSERT_EQ(rows.size(), 6u);  // kappa 1 and 20 always, 4 asked; consecutive and most_moved each
  const std::map<std::string, std::string> m_of_kappa = {{"1", "100"}, {"4", "25"}, {"20", "5"}};  // m = 100 / kappa
  for (const auto& r : rows) EXPECT_EQ(r.at("m"), m_of_kappa.at(r.at("kappa")));
  EXPECT_EQ(rows[0].at("mode"), "consecutive");
  EXPECT_EQ(rows[1].at("mode"), "most_moved");
  EXPECT_TRUE(fs::exists(dir / "out/reintegration_plot.svg"));
}

TEST(BenchReintegration, WithoutADriftedTrajectoryItIsAOneLineError) {
  rekon::test::TempDir dir;
  const std::string data = dataset(dir);
  fs::remove(data + "/drifted_trajectory.txt");
  std::string out;
  EXPECT_EQ(runCommand(rekonBin() + " bench reintegration --dataset " + data + " --out " + (dir / "out"), &out), 1);
  EXPECT_NE(out.find("drifted_trajectory.txt: not found; give --trajectory"), std::string::npos) << out;
}
