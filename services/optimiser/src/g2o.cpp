#include "rekon/optimiser/g2o.hpp"

#include <fmt/format.h>

#include "rekon/common/pose_text.hpp"

namespace rekon::optimiser {

std::string toG2o(const PoseGraph& graph) {
  std::string out;
  for (const auto& [id, pose] : graph.poses()) out += fmt::format("VERTEX_SE3:QUAT {} {}\n", id, poseText(pose));
  if (const auto anchor = graph.anchorId()) out += fmt::format("FIX {}\n", *anchor);
  Matrix6d scale = Matrix6d::Ones();
  scale.bottomRightCorner<3, 3>().setConstant(4.0);
  scale.topRightCorner<3, 3>().setConstant(2.0);
  scale.bottomLeftCorner<3, 3>().setConstant(2.0);
  for (const Constraint& c : graph.constraints()) {
    const Matrix6d info = c.information.cwiseProduct(scale);
    out += fmt::format("EDGE_SE3:QUAT {} {} {}", c.from_id, c.to_id, poseText(c.relative));
    for (int r = 0; r < 6; ++r) {
      for (int col = r; col < 6; ++col) out += fmt::format(" {:.9g}", info(r, col));
    }
    out += '\n';
  }
  return out;
}

}  // namespace rekon::optimiser
