#include "analytic_scene.hpp"
#include "rekon/common/error.hpp"

namespace rekon::synth {

std::unique_ptr<AnalyticScene> makeCorridorScene() { throw Error("scene corridor is not implemented yet; use room or tabletop"); }

}  // namespace rekon::synth
