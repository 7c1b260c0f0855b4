#pragma once

namespace rekon::constrain {

// `rekon constrain --prior KF | --loop FROM,TO --pose "tx ty tz qx qy qz qw"
// [--sigma T,R | --information "36 numbers"] [--source NAME] [--sequence N]`:
// sends one external_constraint_t to the running optimiser (after its
// heartbeat, a few times: repeats count once). Bad input is one line and exit 1.
int constrainCommand(int argc, char** argv);

}  // namespace rekon::constrain
