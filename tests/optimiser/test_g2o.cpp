// The pose graph in g2o's format and back: toG2o and parseG2o are inverses
// (kinds through the loop marker), other tools' files read as odometry,
// damage is one line naming the file and line, and a GraphWorker loaded from
// a session's graph keeps its poses and ignores the same items arriving again.
#include <gtest/gtest.h>

#include <fstream>
#include <ostream>
#include <string>

#include "graph_worker.hpp"
#include "rekon/common/error.hpp"
#include "rekon/optimiser/g2o.hpp"
#include "rekon/optimiser/pose_graph.hpp"
#include "rekon/optimiser/synthetic_graph.hpp"
#include "test_support.hpp"

namespace rekon::optimiser {
namespace {

Pose poseAt(double x, double y, double z, double angle, const Eigen::Vector3d& axis) {
  Pose p = Pose::Identity();
  p.linear() = Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
  p.translation() = Eigen::Vector3d(x, y, z);
  return p;
}

// Positive definite (diagonally dominant) with every block coupled. Entries
// have at most 6 significant digits: toG2o writes 9, so they come back exactly.
Matrix6d coupledInformation(double weight) {
  Matrix6d info;
  for (int r = 0; r < 6; ++r) {
    for (int c = 0; c < 6; ++c) info(r, c) = r == c ? weight * (1000 + 100 * r) : weight * 1.25 * (r + 1) * (c + 1);
  }
  return info;
}

Constraint edge(EdgeKind kind, int64_t from, int64_t to, const PoseGraph& graph, double weight) {
  Constraint c;
  c.kind = kind;
  c.from_id = from;
  c.to_id = to;
  // Off the current poses by a little, as a measurement is.
  c.relative = graph.pose(from)->inverse() * *graph.pose(to) * poseAt(0.01, -0.02, 0.005, 0.01, {1, 2, 3});
  c.information = coupledInformation(weight);
  return c;
}

// Keyframe 5 added first (the anchor, not the lowest id), odometry 5-2-7-9,
// loops 9-5 and 7-5 added between the odometry edges.
void buildGraph(PoseGraph& graph) {
  graph.addKeyframe(5, poseAt(0.1, 0.2, 0.3, 0.2, {0, 0, 1}));
  graph.addKeyframe(2, poseAt(1.0, 0.25, -0.5, 0.7, {1, 1, 0}));
  graph.addKeyframe(7, poseAt(2.0, 1.5, 0.125, -1.1, {0, 1, 1}));
  graph.addKeyframe(9, poseAt(0.3, 2.5, 1.0, 2.9, {1, -2, 0.5}));
  graph.addConstraint(edge(EdgeKind::Odometry, 5, 2, graph, 1.0));
  graph.addConstraint(edge(EdgeKind::Odometry, 2, 7, graph, 2.5));
  graph.addConstraint(edge(EdgeKind::Loop, 9, 5, graph, 0.5));
  graph.addConstraint(edge(EdgeKind::Odometry, 7, 9, graph, 4.0));
  graph.addConstraint(edge(EdgeKind::Loop, 7, 5, graph, 0.25));
}

// toG2o writes 9 decimals: each coordinate and quaternion component (the
// fields of the text) is off by at most 5e-10, plus the renormalisation.
constexpr double kTextTolerance = 1e-9;

void expectSamePose(const Pose& expected, const Pose& actual) {
  EXPECT_LT((expected.translation() - actual.translation()).cwiseAbs().maxCoeff(), kTextTolerance);
  const Eigen::Quaterniond q(expected.linear());
  Eigen::Quaterniond r(actual.linear());
  if (q.dot(r) < 0) r.coeffs() = -r.coeffs();  // the same rotation
  EXPECT_LT((q.coeffs() - r.coeffs()).cwiseAbs().maxCoeff(), kTextTolerance);
}

double relativeDifference(const Matrix6d& expected, const Matrix6d& actual) {
  return (expected - actual).norm() / expected.norm();
}

TEST(G2o, ParsingWhatToG2oWroteGivesBackTheGraph) {
  PoseGraph graph;
  buildGraph(graph);
  const G2oGraph parsed = parseG2o(toG2o(graph), "graph.g2o");

  const auto poses = graph.poses();
  ASSERT_EQ(parsed.vertices.size(), poses.size());
  for (size_t i = 0; i < poses.size(); ++i) {
    EXPECT_EQ(parsed.vertices[i].first, poses[i].first);
    expectSamePose(poses[i].second, parsed.vertices[i].second);
  }
  EXPECT_EQ(parsed.fixed, std::optional<int64_t>(5));

  // Odometry first, then the loops, each in insertion order.
  const std::vector<Constraint> edges = graph.constraints();
  const std::vector<size_t> written_order = {0, 1, 3, 2, 4};
  ASSERT_EQ(parsed.edges.size(), edges.size());
  for (size_t i = 0; i < edges.size(); ++i) {
    const Constraint& expected = edges[written_order[i]];
    const Constraint& actual = parsed.edges[i];
    EXPECT_EQ(actual.kind, expected.kind) << i;
    EXPECT_EQ(actual.from_id, expected.from_id);
    EXPECT_EQ(actual.to_id, expected.to_id);
    expectSamePose(expected.relative, actual.relative);
    EXPECT_LT(relativeDifference(expected.information, actual.information), 1e-9);
  }
}

TEST(G2o, InformationComesBackToNineSignificantDigits) {
  // Any doubles, e.g. a tracker's information times information_scale:
  // toG2o writes 9 significant digits, so each entry is within 5e-9 of itself.
  PoseGraph graph;
  graph.addKeyframe(0, Pose::Identity());
  graph.addKeyframe(1, poseAt(0.5, 0, 0, 0.1, {0, 0, 1}));
  Constraint c = edge(EdgeKind::Odometry, 0, 1, graph, 1.0);
  const Eigen::Matrix<double, 6, 6> a = Eigen::Matrix<double, 6, 6>::Random();
  c.information = a.transpose() * a / 3.0 + Matrix6d::Identity() * 0.1234567890123;
  graph.addConstraint(c);
  const Matrix6d expected = graph.constraints().at(0).information;
  const Matrix6d parsed = parseG2o(toG2o(graph), "graph.g2o").edges.at(0).information;
  EXPECT_TRUE(((parsed - expected).array().abs() <= 5e-9 * expected.array().abs()).all()) << parsed - expected;
  EXPECT_EQ(parsed, parsed.transpose());
}

TEST(G2o, TheLoopMarkerComesAfterTheOdometryEdges) {
  PoseGraph graph;
  buildGraph(graph);
  const std::string text = toG2o(graph);
  const size_t marker = text.find(std::string(kG2oLoopMarker) + "\n");
  ASSERT_NE(marker, std::string::npos) << text;
  EXPECT_EQ(text.find("EDGE_SE3:QUAT 7 9 "), text.find("EDGE_SE3:QUAT", text.find("EDGE_SE3:QUAT 2 7 ") + 1));
  EXPECT_LT(text.find("EDGE_SE3:QUAT 7 9 "), marker);
  EXPECT_GT(text.find("EDGE_SE3:QUAT 9 5 "), marker);
  EXPECT_GT(text.find("EDGE_SE3:QUAT 7 5 "), marker);
}

TEST(G2o, AFileWithoutTheMarkerReadsAsOdometry) {
  // Another tool's file: comments, blank lines, CRLF, g2o's identity information
  // (rotation x4 in g2o's units is 1 in rekon's).
  const std::string text =
      "# written by another tool\r\n"
      "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\r\n"
      "\n"
      "VERTEX_SE3:QUAT 1 1 0 0 0 0 0.6 0.8\r\n"
      "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0.6 0.8 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 4 0 0 4 0 4\r\n"
      "EDGE_SE3:QUAT 1 0 -1 0 0 0 0 -0.6 0.8 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 4 0 0 4 0 4\r\n";
  const G2oGraph g = parseG2o(text, "other.g2o");
  EXPECT_EQ(g.vertices.size(), 2u);
  EXPECT_FALSE(g.fixed.has_value());
  ASSERT_EQ(g.edges.size(), 2u);
  for (const Constraint& c : g.edges) {
    EXPECT_EQ(c.kind, EdgeKind::Odometry);
    EXPECT_LT((c.information - Matrix6d::Identity()).cwiseAbs().maxCoeff(), 1e-15);
  }
}

struct BadLine {
  const char* name;
  std::string line;   // after two good vertices and a comment: it is line 4
  std::string what;   // in the error
};

void PrintTo(const BadLine& bad, std::ostream* os) { *os << bad.name; }

class G2oDamage : public ::testing::TestWithParam<BadLine> {};

TEST_P(G2oDamage, IsOneLineNamingTheFileAndLine) {
  const std::string text = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n"
                           "# a comment\n"
                           "VERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n" +
                           GetParam().line + "\n";
  try {
    parseG2o(text, "/session/graph.g2o");
    FAIL() << "no error for: " << GetParam().line;
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_EQ(what.rfind("/session/graph.g2o:4: ", 0), 0u) << what;
    EXPECT_NE(what.find(GetParam().what), std::string::npos) << what;
    EXPECT_EQ(what.find('\n'), std::string::npos) << what;
  }
}

const std::string kInfo = " 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 4 0 0 4 0 4";

INSTANTIATE_TEST_SUITE_P(
    G2o, G2oDamage,
    ::testing::Values(BadLine{"UnknownTag", "VERTEX_SE2 2 0 0 0", "unknown tag 'VERTEX_SE2'"},
                      BadLine{"MissingField", "VERTEX_SE3:QUAT 2 0 0 0 0 0 0", "missing field 'qw'"},
                      BadLine{"ExtraField", "FIX 0 1", "unexpected field '1'"},
                      BadLine{"NotANumber", "VERTEX_SE3:QUAT 2 0 zero 0 0 0 0 1", "'y' is 'zero', not a number"},
                      BadLine{"IdNotAnInteger", "VERTEX_SE3:QUAT 2.5 0 0 0 0 0 0 1", "not a number"},
                      BadLine{"NaN", "VERTEX_SE3:QUAT 2 0 0 nan 0 0 0 1", "'z' is 'nan', not finite"},
                      BadLine{"InfiniteInformation", "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 inf" + kInfo.substr(2),
                              "'information(0,0)' is 'inf', not finite"},
                      BadLine{"NonUnitQuaternion", "VERTEX_SE3:QUAT 2 0 0 0 0 0 0 1.01",
                              "quaternion norm 1.01 is not 1"},
                      BadLine{"DuplicateVertex", "VERTEX_SE3:QUAT 1 0 0 0 0 0 0 1",
                              "vertex 1 is defined a second time (first on line 3)"},
                      BadLine{"EdgeToUnknownVertex", "EDGE_SE3:QUAT 0 9 1 0 0 0 0 0 1" + kInfo,
                              "vertex 9 is not defined"},
                      BadLine{"FixOfUnknownVertex", "FIX 3", "vertex 3 is not defined"},
                      BadLine{"ShortEdge", "EDGE_SE3:QUAT 0 1 1 0 0 0 0 0 1 1 0 0",
                              "missing field 'information(0,3)'"}),
    [](const ::testing::TestParamInfo<BadLine>& p) { return std::string(p.param.name); });

TEST(G2o, ASecondFixIsAnError) {
  EXPECT_THROW(parseG2o("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nFIX 0\nFIX 0\n", "graph.g2o"), Error);
}

TEST(G2o, AMissingFileIsAnErrorNamingIt) {
  try {
    readG2oFile("/nonexistent/graph.g2o");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/graph.g2o"), std::string::npos) << e.what();
  }
}

TEST(G2o, ReadsTheFileToG2oWrote) {
  PoseGraph graph;
  buildGraph(graph);
  test::TempDir dir;
  std::ofstream(dir / "graph.g2o") << toG2o(graph);
  EXPECT_EQ(readG2oFile(dir / "graph.g2o").edges.size(), 5u);
}

TEST(GraphWorkerLoad, TheFixedVertexAnchorsTheGraphAndItemsArrivingAgainAreDuplicates) {
  PoseGraph graph;
  buildGraph(graph);
  const G2oGraph g2o = parseG2o(toG2o(graph), "graph.g2o");
  GraphWorker worker(PoseGraphParams{});
  worker.load(g2o);
  EXPECT_EQ(worker.graph().anchorId(), std::optional<int64_t>(5));
  EXPECT_EQ(worker.graph().numConstraints(), 5u);
  EXPECT_EQ(worker.graph().numLoopEdges(), 2u);

  // A tracker's replay of the same keyframe and constraints (its own copies,
  // not the parsed ones).
  const std::vector<Constraint> edges = graph.constraints();
  const bool new_edges = worker.apply({KeyframeIn{2, *graph.pose(2)}, edges[0], edges[2]});
  EXPECT_FALSE(new_edges);
  EXPECT_EQ(worker.duplicates(), 3);
  EXPECT_EQ(worker.graph().numConstraints(), 5u);
}

TEST(GraphWorkerLoad, WithoutFixTheLowestIdAnchorsTheGraph) {
  const G2oGraph g2o = parseG2o("VERTEX_SE3:QUAT 4 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 3 1 0 0 0 0 0 1\n", "graph.g2o");
  GraphWorker worker(PoseGraphParams{});
  worker.load(g2o);
  EXPECT_EQ(worker.graph().anchorId(), std::optional<int64_t>(3));
}

TEST(GraphWorkerLoad, KeepsTheSessionsOptimisedPoses) {
  // An optimised lap closed by one loop edge; its odometry alone has drifted
  // by centimetres at the lap's end.
  SyntheticGraphSpec spec;
  spec.keyframes = 60;
  spec.sigma_translation_m = 0.003;
  spec.sigma_rotation_rad = 0.0003;
  const SyntheticGraph g = makeSyntheticGraph(spec);
  PoseGraph graph;
  for (size_t i = 0; i < g.initial.size(); ++i) graph.addKeyframe(static_cast<int64_t>(i), g.initial[i]);
  for (const Constraint& c : g.constraints) graph.addConstraint(c);
  Constraint loop = g.constraints.front();
  loop.kind = EdgeKind::Loop;
  loop.from_id = 59;
  loop.to_id = 0;
  loop.relative = g.truth[59].inverse() * g.truth[0];
  graph.addConstraint(loop);
  graph.optimise(true);

  GraphWorker worker(PoseGraphParams{});
  worker.load(parseG2o(toG2o(graph), "graph.g2o"));
  // Loaded, the keyframes other than the anchor have moved together (by the
  // residual of the first edge to the anchor), not along their odometry.
  const auto relativeTo1 = [](const PoseGraph& pg, int64_t id) { return Pose(pg.pose(1)->inverse() * *pg.pose(id)); };
  double worst = 0.0;
  for (int64_t id = 2; id < spec.keyframes; ++id)
    worst = std::max(worst, translationDistance(relativeTo1(graph, id), relativeTo1(worker.graph(), id)));
  EXPECT_LT(worst, 1e-8);

  // The first optimisation takes the rigid move back.
  worker.optimise(false, -1);
  worst = 0.0;
  for (const auto& [id, pose] : graph.poses())
    worst = std::max(worst, translationDistance(pose, *worker.graph().pose(id)));
  EXPECT_LT(worst, 1e-4);
}

// A culled graph (three laps of a room, revisits culled onto the first lap) written and loaded into a
// worker that does not cull: every culled keyframe comes back linked to its kept keyframe, so it moves
// with the graph instead of staying where the file put it.
TEST(GraphWorkerLoad, CulledKeyframesComeBackHeldToTheKeyframesTheyWereCulledOnto) {
  const SyntheticGraph g = makeSyntheticGraph({.keyframes = 120, .laps = 3, .loop_edges = 300, .seed = 11});
  PoseGraphParams culling;
  culling.cull_radius_m = 0.2;
  culling.cull_angle_deg = 15.0;
  PoseGraph graph(culling);
  for (size_t k = 0; k < g.initial.size(); ++k) {
    graph.addKeyframe(static_cast<int64_t>(k), g.initial[k]);
    for (const Constraint& c : g.constraints) {
      if (std::max(c.from_id, c.to_id) == static_cast<int64_t>(k)) graph.addConstraint(c);
    }
    graph.optimise(false);
  }
  graph.optimise(true);
  const std::vector<Constraint> links = graph.cullLinks();
  ASSERT_GE(links.size(), 12u);  // 24 culled (test_pose_graph_culling.cpp)

  GraphWorker worker(PoseGraphParams{});
  worker.load(parseG2o(toG2o(graph), "graph.g2o"));
  worker.optimise(true, -1);
  for (const Constraint& link : links) {
    EXPECT_TRUE(worker.graph().isAttached(link.to_id)) << link.to_id;
    const Pose in_kept = worker.graph().pose(link.from_id)->inverse() * *worker.graph().pose(link.to_id);
    EXPECT_LT(translationDistance(in_kept, link.relative), 1e-6) << link.to_id;
  }
  double worst = 0.0;
  for (const auto& [id, pose] : graph.poses())
    worst = std::max(worst, translationDistance(pose, *worker.graph().pose(id)));
  std::printf("loaded and optimised again: at most %.4f mm from the culled graph's poses\n", 1e3 * worst);
  EXPECT_LT(worst, 1e-4);
}

}  // namespace
}  // namespace rekon::optimiser
