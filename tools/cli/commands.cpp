#include "commands.hpp"

#include "rekon/tracker/odometry_command.hpp"

#include "rekon/synth/synth.hpp"

namespace rekon {

const std::vector<Command>& commands() {
  static const std::vector<Command> table = {
      {"odometry", "dense RGB-D odometry (DVO) in-process on a dataset; writes a TUM trajectory", tracker::odometryMain},
      {"synth", "write a synthetic RGB-D sequence with exact ground truth", &synth::synthCommand},
  };
  return table;
}

}  // namespace rekon
