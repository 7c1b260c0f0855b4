// External constraints (messages/external_constraint.lcm): the optimiser's
// checks of what arrives, how a GraphWorker adds them (absolute priors as
// edges from the fixed first keyframe, each once, waiting for their
// keyframes, contradictory ones removed), and `rekon constrain`'s one line
// for bad input.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "graph_worker.hpp"
#include "rekon/common/error.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/optimiser/graph_messages.hpp"
#include "test_support.hpp"

namespace rekon::optimiser {
namespace {

constexpr int kKeyframes = 10;
constexpr double kStep = 0.2;   // metres between true keyframes, along x
constexpr double kDrift = 0.02; // metres of odometry error per edge, along y (20 cm over the chain)

Pose truth(int k) {
  Pose p = Pose::Identity();
  p.translation() = Eigen::Vector3d(kStep * k, 0, 0);
  return p;
}

Matrix6d diagonalInformation(double sigma_t, double sigma_r) {
  Matrix6d info = Matrix6d::Zero();
  info.diagonal() << Eigen::Vector3d::Constant(1 / (sigma_t * sigma_t)), Eigen::Vector3d::Constant(1 / (sigma_r * sigma_r));
  return info;
}

// A drifted chain as a tracker sends it: keyframes at the odometry's poses,
// odometry edges 1 cm / 0.01 rad, each with kDrift of error.
std::vector<GraphItem> driftedChain() {
  std::vector<GraphItem> items;
  Pose odometry = truth(0);
  Pose step = Pose::Identity();
  step.translation() = Eigen::Vector3d(kStep, kDrift, 0);
  for (int k = 0; k < kKeyframes; ++k) {
    if (k > 0) odometry = odometry * step;
    items.push_back(KeyframeIn{k, odometry});
    if (k > 0) items.push_back(Constraint{EdgeKind::Odometry, k - 1, k, step, diagonalInformation(0.01, 0.01)});
  }
  return items;
}

ExternalConstraint prior(int64_t keyframe, const Pose& pose, int64_t sequence, double sigma = 0.01) {
  rekon_msgs::external_constraint_t m{};
  m.source = "test";
  m.sequence = sequence;
  m.kind = rekon_msgs::external_constraint_t::KIND_PRIOR;
  m.to_id = keyframe;
  m.pose = toMsg(pose);
  toArray(diagonalInformation(sigma, sigma), m.information);
  return externalConstraintFromMsg(m);
}

double errorAt(const GraphWorker& w, int k) { return (w.graph().pose(k)->translation() - truth(k).translation()).norm(); }

std::string whyRejected(rekon_msgs::external_constraint_t m) {
  try {
    externalConstraintFromMsg(m);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

rekon_msgs::external_constraint_t validLoop() {
  rekon_msgs::external_constraint_t m{};
  m.source = "operator";
  m.sequence = 7;
  m.kind = rekon_msgs::external_constraint_t::KIND_LOOP;
  m.from_id = 1;
  m.to_id = 4;
  m.pose = toMsg(Pose::Identity());
  toArray(diagonalInformation(0.01, 0.01), m.information);
  return m;
}

}  // namespace

TEST(ExternalConstraints, MalformedOnesAreRejectedWithALineNamingThem) {
  EXPECT_EQ(whyRejected(validLoop()), "");
  auto m = validLoop();
  m.kind = 9;
  EXPECT_NE(whyRejected(m).find("external constraint 7 from operator has unknown kind 9"), std::string::npos);
  m = validLoop();
  m.pose.t[2] = std::nan("");
  EXPECT_NE(whyRejected(m).find("(loop 1 -> 4) has a non-finite pose"), std::string::npos);
  m = validLoop();
  m.pose.q[3] = 2.0;
  EXPECT_NE(whyRejected(m).find("quaternion that is not unit"), std::string::npos);
  m = validLoop();
  m.information[7] = INFINITY;
  EXPECT_NE(whyRejected(m).find("non-finite information matrix"), std::string::npos);
  m = validLoop();
  m.to_id = 1;
  EXPECT_NE(whyRejected(m).find("links a keyframe to itself"), std::string::npos);
}

TEST(ExternalConstraints, AFewAbsolutePriorsPullADriftedChainBack) {
  GraphWorker without(PoseGraphParams{}), with(PoseGraphParams{});
  without.apply(driftedChain());
  with.apply(driftedChain());
  EXPECT_TRUE(with.applyExternal({prior(3, truth(3), 1), prior(6, truth(6), 2), prior(9, truth(9), 3)}));
  without.optimise(true, 0);
  with.optimise(true, 0);
  EXPECT_EQ(with.externalConstraintsAdded(), 3);
  EXPECT_EQ(with.graph().loopEdgesRemoved(), 0u);
  // Without priors keyframe 9 stays where the odometry put it: 9 x 2 cm off.
  EXPECT_NEAR(errorAt(without, 9), 9 * kDrift, 1e-6);
  // With them every keyframe is back near the truth: the least-squares
  // compromise between 1 cm priors and 1 cm odometry edges leaves at most
  // 18.9 mm (measured, keyframe 9 at the chain's end, where one prior faces
  // three drifted edges; 4.1 mm or less up to keyframe 6) and at most 0.105
  // of the error without priors. Bounds: 2.5 cm and 0.15, about 30 % over.
  for (int k = 1; k < kKeyframes; ++k) {
    std::printf("keyframe %d: %.4f m without, %.4f m with\n", k, errorAt(without, k), errorAt(with, k));
    EXPECT_LT(errorAt(with, k), 0.025) << "keyframe " << k;
    EXPECT_LT(errorAt(with, k), 0.15 * errorAt(without, k)) << "keyframe " << k;
  }
}

TEST(ExternalConstraints, AContradictoryPriorIsRemovedAndTheOthersHold) {
  GraphWorker w(PoseGraphParams{});
  w.apply(driftedChain());
  Pose wrong = truth(5);
  wrong.translation().z() += 1.0;  // a metre off, at 1 cm claimed
  w.applyExternal({prior(3, truth(3), 1), prior(5, wrong, 2), prior(6, truth(6), 3), prior(9, truth(9), 4)});
  w.optimise(true, 0);
  EXPECT_EQ(w.graph().loopEdgesRemoved(), 1u);  // the wrong prior, with a warning naming it
  EXPECT_EQ(w.graph().numLoopEdges(), 3u);
  // As without the wrong prior (the test above): measured at most 18.9 mm, bound 2.5 cm.
  for (int k = 1; k < kKeyframes; ++k) EXPECT_LT(errorAt(w, k), 0.025) << "keyframe " << k;
}

TEST(ExternalConstraints, RepeatsCountOnceAndAPriorWaitsForItsKeyframe) {
  GraphWorker w(PoseGraphParams{});
  // Sent three times (UDP), before the tracker has keyframe 9: nothing to add yet.
  EXPECT_FALSE(w.applyExternal({prior(9, truth(9), 5), prior(9, truth(9), 5), prior(9, truth(9), 5)}));
  EXPECT_EQ(w.duplicates(), 2);
  EXPECT_EQ(w.constraintsWaiting(), 1u);
  EXPECT_TRUE(w.apply(driftedChain()));
  EXPECT_EQ(w.constraintsWaiting(), 0u);
  EXPECT_EQ(w.externalConstraintsAdded(), 1);
}

TEST(ExternalConstraints, APriorOnTheFixedFirstKeyframeOrWithSingularInformationIsRejected) {
  GraphWorker w(PoseGraphParams{});
  w.apply(driftedChain());
  w.applyExternal({prior(0, truth(0), 1)});
  EXPECT_EQ(w.rejected(), 1);  // "is on the first keyframe, which is fixed"
  auto singular = prior(4, truth(4), 2);
  singular.information(5, 5) = 0;  // yaw unconstrained: not positive definite
  w.applyExternal({singular});
  EXPECT_EQ(w.rejected(), 2);
  EXPECT_EQ(w.externalConstraintsAdded(), 0);
}

TEST(ExternalConstraints, ConstrainCommandRejectsBadInputWithOneLine) {
  const std::string rekon = test::binDir() + "/rekon constrain --wait 0 ";
  struct Case {
    std::string args, words;
  };
  const std::vector<Case> cases = {
      {"--pose \"0 0 0 0 0 0 1\"", "give one of --prior KEYFRAME or --loop FROM,TO"},
      {"--prior 3 --pose \"0 0 0 0 0 1\"", "--pose needs 7 numbers"},
      {"--prior x --pose \"0 0 0 0 0 0 1\"", "--prior must be a keyframe id"},
      {"--loop 3 --pose \"0 0 0 0 0 0 1\"", "--loop needs FROM,TO"},
      {"--prior 3 --pose \"0 0 0 0 0 0 2\"", "quaternion that is not unit"},
      {"--prior 3 --pose \"0 0 0 0 0 0 1\" --sigma 0,0.01", "--sigma T,R must be two positive numbers"},
  };
  for (const Case& c : cases) {
    std::string out;
    EXPECT_EQ(test::runCommand(rekon + c.args, &out), 1) << c.args << "\n" << out;
    EXPECT_NE(out.find(c.words), std::string::npos) << c.args << "\n" << out;
    EXPECT_EQ(test::crashLines(out), "") << out;
  }
}

}  // namespace rekon::optimiser
