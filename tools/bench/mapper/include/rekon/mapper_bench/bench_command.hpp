#pragma once
// `rekon bench keyframes | reintegration | peers`: the paper's Figures 5 and
// 7 measured on rekon's own mapper, and its TSDF volume against its peers
// (tools/bench/mapper/README.md).

namespace rekon::mapper_bench {

// `rekon bench SUBCOMMAND ...`: dispatches to the two below.
int benchCommand(int argc, char** argv);
// Figure 5: keyframe strategies, average keyframe size against CORR / COMPL.
int benchKeyframesCommand(int argc, char** argv);
// Figure 7: amortised (re-)integration time per frame against kappa.
int benchReintegrationCommand(int argc, char** argv);
// Issue 19: TSDF integration against OpenCV's and Open3D's on the same frames.
int benchPeersCommand(int argc, char** argv);

}  // namespace rekon::mapper_bench
