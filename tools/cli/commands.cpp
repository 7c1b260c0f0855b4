#include "commands.hpp"

namespace rekon {

const std::vector<Command>& commands() {
  static const std::vector<Command> table = {
  };
  return table;
}

}  // namespace rekon
