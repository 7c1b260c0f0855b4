#include "commands.hpp"

#include "rekon/synth/synth.hpp"

namespace rekon {

const std::vector<Command>& commands() {
  static const std::vector<Command> table = {
      {"synth", "write a synthetic RGB-D sequence with exact ground truth", &synth::synthCommand},
  };
  return table;
}

}  // namespace rekon
