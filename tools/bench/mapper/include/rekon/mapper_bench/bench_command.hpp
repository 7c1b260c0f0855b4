#pragma once
// `rekon bench keyframes | reintegration | peers | scaling`: the paper's
// Figures 5 and 7 measured on rekon's own mapper, its TSDF volume against its
// peers, and its times as the map grows (tools/bench/mapper/README.md).

namespace rekon::mapper_bench {

// `rekon bench SUBCOMMAND ...`: dispatches to the two below.
int benchCommand(int argc, char** argv);
// Figure 5: keyframe strategies, average keyframe size against CORR / COMPL.
int benchKeyframesCommand(int argc, char** argv);
// Figure 7: amortised (re-)integration time per frame against kappa.
int benchReintegrationCommand(int argc, char** argv);
// Issue 19: TSDF integration against OpenCV's and Open3D's on the same frames.
int benchPeersCommand(int argc, char** argv);
// Issue 19: integration and re-integration time as the map grows (synthetic corridor).
int benchScalingCommand(int argc, char** argv);

}  // namespace rekon::mapper_bench
