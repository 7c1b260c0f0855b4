#include "rekon/optimiser/g2o.hpp"

#include <fmt/format.h>

#include <charconv>
#include <cmath>
#include <map>
#include <sstream>
#include <string_view>
#include <type_traits>
#include <utility>

#include "rekon/common/error.hpp"
#include "rekon/common/image_io.hpp"
#include "rekon/common/pose_text.hpp"

namespace rekon::optimiser {
namespace {

// A quaternion further than this from unit length is damage, not rounding
// (toG2o writes 9 decimals).
constexpr double kQuaternionNormTolerance = 1e-3;

// rekon's information times this (element-wise) is g2o's (see the header).
Matrix6d g2oInformationScale() {
  Matrix6d scale = Matrix6d::Ones();
  scale.bottomRightCorner<3, 3>().setConstant(4.0);
  scale.topRightCorner<3, 3>().setConstant(2.0);
  scale.bottomLeftCorner<3, 3>().setConstant(2.0);
  return scale;
}

void appendEdge(const Constraint& c, const Matrix6d& scale, std::string& out) {
  const Matrix6d info = c.information.cwiseProduct(scale);
  out += fmt::format("EDGE_SE3:QUAT {} {} {}", c.from_id, c.to_id, poseText(c.relative));
  for (int r = 0; r < 6; ++r) {
    for (int col = r; col < 6; ++col) out += fmt::format(" {:.9g}", info(r, col));
  }
  out += '\n';
}

// The fields of one line, read left to right; every problem is a rekon::Error
// naming the file and the line.
class Fields {
 public:
  Fields(const std::string& line, std::string where) : in_(line), where_(std::move(where)) {}

  [[noreturn]] void fail(const std::string& what) const { throw Error(where_ + ": " + what + "; fix the line"); }

  std::string next(std::string_view what) {
    std::string field;
    if (!(in_ >> field)) fail(fmt::format("missing field '{}'", what));
    return field;
  }

  template <class T>
  T number(std::string_view what) {
    const std::string field = next(what);
    T value{};
    const auto [end, ec] = std::from_chars(field.data(), field.data() + field.size(), value);
    if (ec != std::errc() || end != field.data() + field.size())
      fail(fmt::format("field '{}' is '{}', not a number", what, field));
    if constexpr (std::is_floating_point_v<T>) {
      if (!std::isfinite(value)) fail(fmt::format("field '{}' is '{}', not finite", what, field));
    }
    return value;
  }

  // "x y z qx qy qz qw".
  Pose pose() {
    const double x = number<double>("x"), y = number<double>("y"), z = number<double>("z");
    const double qx = number<double>("qx"), qy = number<double>("qy"), qz = number<double>("qz");
    const Eigen::Quaterniond q(number<double>("qw"), qx, qy, qz);
    if (std::abs(q.norm() - 1.0) > kQuaternionNormTolerance)
      fail(fmt::format("quaternion norm {:.6g} is not 1", q.norm()));
    return poseFromQuatTrans(q, Eigen::Vector3d(x, y, z));
  }

  void end() {
    std::string extra;
    if (in_ >> extra) fail(fmt::format("unexpected field '{}' at the end", extra));
  }

 private:
  std::istringstream in_;
  std::string where_;
};

// Reads a g2o file line by line into a G2oGraph.
class G2oParser {
 public:
  explicit G2oParser(std::string name) : name_(std::move(name)) {}

  void line(const std::string& text, int line_no) {
    const auto first = text.find_first_not_of(" \t\r");
    if (first == std::string::npos) return;
    if (text[first] == '#') {
      loops_ |= text.substr(first, text.find_last_not_of(" \t\r") + 1 - first) == kG2oLoopMarker;
      return;
    }
    Fields fields(text, fmt::format("{}:{}", name_, line_no));
    const std::string tag = fields.next("tag");
    if (tag == "VERTEX_SE3:QUAT") {
      vertex(fields, line_no);
    } else if (tag == "FIX") {
      fix(fields);
    } else if (tag == "EDGE_SE3:QUAT") {
      edge(fields);
    } else {
      fields.fail(fmt::format("unknown tag '{}' (rekon reads VERTEX_SE3:QUAT, FIX and EDGE_SE3:QUAT)", tag));
    }
    fields.end();
  }

  G2oGraph take() { return std::move(graph_); }

 private:
  void vertex(Fields& fields, int line_no) {
    const auto id = fields.number<int64_t>("id");
    const auto [it, added] = vertex_lines_.emplace(id, line_no);
    if (!added) fields.fail(fmt::format("vertex {} is defined a second time (first on line {})", id, it->second));
    graph_.vertices.emplace_back(id, fields.pose());
  }

  void fix(Fields& fields) {
    if (graph_.fixed) fields.fail(fmt::format("a second fixed vertex (vertex {} is fixed already)", *graph_.fixed));
    graph_.fixed = knownVertex(fields, "id");
  }

  void edge(Fields& fields) {
    Constraint c;
    c.kind = loops_ ? EdgeKind::Loop : EdgeKind::Odometry;
    c.from_id = knownVertex(fields, "from");
    c.to_id = knownVertex(fields, "to");
    c.relative = fields.pose();
    Matrix6d upper = Matrix6d::Zero();
    for (int r = 0; r < 6; ++r) {
      for (int col = r; col < 6; ++col)
        upper(r, col) = fields.number<double>(fmt::format("information({},{})", r, col));
    }
    upper = upper.cwiseQuotient(g2oInformationScale());
    c.information = upper.selfadjointView<Eigen::Upper>();
    graph_.edges.push_back(c);
  }

  int64_t knownVertex(Fields& fields, std::string_view what) {
    const auto id = fields.number<int64_t>(what);
    if (!vertex_lines_.count(id)) fields.fail(fmt::format("vertex {} is not defined by a line above", id));
    return id;
  }

  std::string name_;
  G2oGraph graph_;
  std::map<int64_t, int> vertex_lines_;  // id -> line defining it
  bool loops_ = false;                   // past kG2oLoopMarker
};

}  // namespace

std::string toG2o(const PoseGraph& graph) {
  std::string out;
  for (const auto& [id, pose] : graph.poses()) out += fmt::format("VERTEX_SE3:QUAT {} {}\n", id, poseText(pose));
  if (const auto anchor = graph.anchorId()) out += fmt::format("FIX {}\n", *anchor);
  const Matrix6d scale = g2oInformationScale();
  const std::vector<Constraint> edges = graph.constraints();
  for (const Constraint& c : edges) {
    if (c.kind == EdgeKind::Odometry) appendEdge(c, scale, out);
  }
  for (const Constraint& c : graph.cullLinks()) appendEdge(c, scale, out);
  out += fmt::format("{}\n", kG2oLoopMarker);
  for (const Constraint& c : edges) {
    if (c.kind == EdgeKind::Loop) appendEdge(c, scale, out);
  }
  return out;
}

G2oGraph parseG2o(const std::string& text, const std::string& name) {
  G2oParser parser(name);
  std::istringstream in(text);
  std::string line;
  for (int line_no = 1; std::getline(in, line); ++line_no) parser.line(line, line_no);
  return parser.take();
}

G2oGraph readG2oFile(const std::string& path) {
  const std::vector<uint8_t> bytes = readFileBytes(path);
  return parseG2o(std::string(bytes.begin(), bytes.end()), path);
}

}  // namespace rekon::optimiser
