#pragma once
// `rekon run`: every service as its own process from one config, watched,
// restarted when it can recover, stopped cleanly downstream, outputs and
// stats collected into --out.
#include <string>
#include <vector>

namespace rekon {

struct RunOptions {
  std::string dataset;                   // a TUM dataset (the player), or
  std::string camera, calibration, record;  // a live camera (rekon-camera), see rekon run --help
  std::string playback;  // with --camera realsense: a .bag recording played at its recorded rate (rekon-realsense)
  std::string out, config_file;
  std::string session;  // a new folder kept as the run goes (session.dir), for rekon remesh and rekon export
  std::string continued;  // a session this run extends (session.dir with session.continue)
  bool localise_only = false;  // with `continued`: only localise in its map (session.localise_only)
  std::vector<std::string> sets;
  bool report = false;  // also write report.html
  bool view = false;    // also start rekon-viewer (a live web page of the run; its URL is printed)
  bool force = false;   // --out may hold an earlier run: its files are replaced
};

// Runs the pipeline to the end of the data (or Ctrl-C); returns the exit
// code: 0, 1 after a failure (named in the last log line), 130 when interrupted.
int launch(const RunOptions& options);

// `rekon run --dataset DIR|--camera DEVICE --out DIR [--config FILE] [--set key=value ...]`
int runCommand(int argc, char** argv);
// `rekon demo [--out DIR]`: the whole pipeline on the built-in default scene.
int demoCommand(int argc, char** argv);
// `rekon chaos --dataset DIR --out DIR [--every S[-S]] [--seed N]`: the dataset
// run twice at its recorded rate, the second time with a random service
// killed (kill -9) every few seconds; the two compared against bounds (chaos.cpp).
int chaosCommand(int argc, char** argv);

}  // namespace rekon
