// rekon-optimiser as a process: this test publishes a synthetic tracker's
// keyframes, constraints (one loop, two malformed), tracked frames and done
// over the bus, and checks the graph updates and trajectory.txt it gets back.
// The test re-runs itself inside a private network namespace
// (tests/support/in_netns.sh) so that its bus meets no other test.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <map>
#include <mutex>
#include <thread>

#include "rekon/common/bus.hpp"
#include "rekon/common/graph_update.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/optimiser/synthetic_graph.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/heartbeat_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"
#include "test_support.hpp"


namespace rekon::optimiser {
namespace {

constexpr int kKeyframes = 40;
constexpr int kFramesPerKeyframe = 3;  // the keyframe's own frame and two after it

using Clock = std::chrono::steady_clock;

pid_t spawnOptimiser(const std::string& out_dir) {
  // The synthetic constraints' information is calibrated: no scaling.
  return test::spawnShell("exec " + test::binDir() + "/rekon-optimiser --out " + out_dir +
                          " --set optimiser.information_scale=1 > " + out_dir + "/optimiser.log 2>&1");
}

// Waits up to `timeout` for `done`, with the bus dispatched on this thread.
template <class Pred>
bool spinUntil(Bus& bus, Pred done, std::chrono::seconds timeout) {
  const auto end = Clock::now() + timeout;
  while (!done()) {
    if (Clock::now() > end) return false;
    bus.handle(20);
  }
  return true;
}

TEST(OptimiserService, ClosesTheLoopAndWritesEveryTrackedFrame) {
  if (!test::insideNetns()) return;
  test::TempDir dir;
  LcmBus bus(BusOptions{});

  std::atomic<bool> running{false};
  std::mutex mutex;
  std::vector<rekon_msgs::graph_update_t> updates;
  int optimiser_done = 0;
  bus.subscribe<rekon_msgs::heartbeat_t>(channel::kHeartbeat, [&](const rekon_msgs::heartbeat_t& m) {
    if (m.service == "optimiser" && m.state == "running") running = true;
  });
  bus.subscribe<rekon_msgs::graph_update_t>(channel::kGraphUpdates, [&](const rekon_msgs::graph_update_t& m) {
    std::lock_guard<std::mutex> lock(mutex);
    updates.push_back(m);
  });
  bus.subscribe<rekon_msgs::done_t>(channel::kDone, [&](const rekon_msgs::done_t& m) {
    if (m.service == "optimiser") ++optimiser_done;
  });

  const pid_t pid = spawnOptimiser(dir.path());
  ASSERT_GT(pid, 0);
  // "running" is announced after the optimiser subscribed to its inputs.
  ASSERT_TRUE(spinUntil(bus, [&] { return running.load(); }, std::chrono::seconds(20)))
      << test::readText(dir / "optimiser.log");

  SyntheticGraphSpec spec;
  spec.keyframes = kKeyframes;
  spec.sigma_translation_m = 0.003;
  spec.sigma_rotation_rad = 0.0003;
  spec.seed = 11;
  const SyntheticGraph g = makeSyntheticGraph(spec);
  // Keeps our receive queue drained and leaves the optimiser's bus thread
  // time to read, so that no socket buffer overflows on a loaded machine.
  const auto pace = [&] {
    bus.handle(1);
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  };
  std::map<int64_t, std::pair<int64_t, Pose>> frames;  // frame id -> (keyframe, pose in keyframe)
  for (int k = 0; k < kKeyframes; ++k) {
    rekon_msgs::keyframe_t kf{};
    kf.keyframe_id = k;
    kf.frame_id = k * kFramesPerKeyframe;
    kf.timestamp = 0.1 * kf.frame_id;
    kf.pose_world = toMsg(g.initial[k]);
    bus.publish(channel::kKeyframes, kf);
    if (k > 0) {
      const Constraint& c = g.constraints[k - 1];
      rekon_msgs::constraint_t m{};
      m.kind = rekon_msgs::constraint_t::KIND_ODOMETRY;
      m.from_id = c.from_id;
      m.to_id = c.to_id;
      m.relative = toMsg(c.relative);
      toArray(c.information, m.information);
      bus.publish(channel::kConstraints, m);
    }
    for (int f = 0; f < kFramesPerKeyframe; ++f) {
      rekon_msgs::tracked_frame_t tf{};
      tf.frame_id = k * kFramesPerKeyframe + f;
      tf.timestamp = 0.1 * tf.frame_id;
      tf.keyframe_id = k;
      Pose in_kf = Pose::Identity();
      in_kf.translation() = Eigen::Vector3d(0.01 * f, 0.0, 0.02 * f);
      tf.pose_in_keyframe = toMsg(in_kf);
      bus.publish(channel::kTrackedFrames, tf);
      frames[tf.frame_id] = {k, in_kf};
    }
    pace();
  }
  // Malformed: NaN information, and an edge to a keyframe that never came.
  rekon_msgs::constraint_t bad{};
  bad.kind = rekon_msgs::constraint_t::KIND_LOOP;
  bad.from_id = 3;
  bad.to_id = 5;
  bad.relative = toMsg(Pose::Identity());
  toArray(isotropicInformation(0.01, 0.01), bad.information);
  bad.information[7] = std::nan("");
  bus.publish(channel::kConstraints, bad);
  bad.information[7] = 1e4;
  bad.to_id = 999;
  bus.publish(channel::kConstraints, bad);
  // The loop: the last keyframe seen from the first.
  rekon_msgs::constraint_t loop{};
  loop.kind = rekon_msgs::constraint_t::KIND_LOOP;
  loop.from_id = kKeyframes - 1;
  loop.to_id = 0;
  loop.relative = toMsg(g.truth[kKeyframes - 1].inverse() * g.truth[0]);
  toArray(g.constraints[0].information, loop.information);
  bus.publish(channel::kConstraints, loop);
  pace();
  rekon_msgs::done_t tracker_done{};
  tracker_done.service = "tracker";
  tracker_done.last_frame_id = kKeyframes * kFramesPerKeyframe - 1;
  for (int i = 0; i < 3; ++i) {
    bus.publish(channel::kDone, tracker_done);
    pace();
  }

  const bool done = spinUntil(bus, [&] { return optimiser_done > 0; }, std::chrono::seconds(30));
  int status = -1;
  if (!done) kill(pid, SIGTERM);
  waitpid(pid, &status, 0);
  ASSERT_TRUE(done) << "no done_t from the optimiser\n" << test::readText(dir / "optimiser.log");
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << test::readText(dir / "optimiser.log");

  // Graph updates: versions increase; the final one arrives (sent three times,
  // the filter passes it once) and holds every keyframe.
  GraphUpdateFilter filter;
  const rekon_msgs::graph_update_t* final_update = nullptr;
  int64_t previous = 0;
  for (const auto& u : updates) {
    EXPECT_GE(u.version, previous) << "versions never go back";
    previous = u.version;
    if (filter.accept(u.version) && u.final_update) final_update = &u;
  }
  ASSERT_NE(final_update, nullptr) << test::readText(dir / "optimiser.log");
  ASSERT_EQ(final_update->num_keyframes, kKeyframes);
  std::vector<std::pair<int64_t, Pose>> final_poses;
  for (int i = 0; i < kKeyframes; ++i) final_poses.emplace_back(final_update->keyframe_ids[i], *fromMsg(final_update->poses[i]));
  // One exact loop edge over 40 noisy odometry edges: every keyframe within
  // 4 standard deviations of the Brownian bridge the closed loop leaves
  // (loopClosureErrorBound) plus 1 mm; the last keyframe within 1 cm.
  for (const auto& [id, pose] : final_poses) {
    EXPECT_LT((pose.translation() - g.truth[static_cast<size_t>(id)].translation()).norm(),
              loopClosureErrorBound(spec, static_cast<int>(id), 4.0) + 0.001)
        << "keyframe " << id;
  }
  EXPECT_LT((final_poses.back().second.translation() - g.truth.back().translation()).norm(), 0.01);
  EXPECT_GT((g.initial.back().translation() - g.truth.back().translation()).norm(), 0.01)
      << "the odometry alone must miss that for the test to mean something";

  // trajectory.txt: every tracked frame, in order, = final keyframe pose x pose in keyframe.
  const Trajectory trajectory = readTumTrajectory(dir / "trajectory.txt");
  ASSERT_EQ(trajectory.size(), frames.size());
  size_t i = 0;
  for (const auto& [frame_id, kf_and_pose] : frames) {
    const Pose expected = final_poses[static_cast<size_t>(kf_and_pose.first)].second * kf_and_pose.second;
    EXPECT_NEAR(trajectory[i].timestamp, 0.1 * static_cast<double>(frame_id), 1e-6);
    // TUM files carry a few decimals: 1e-4 m is well within them.
    EXPECT_LT((trajectory[i].pose.translation() - expected.translation()).norm(), 1e-4) << "frame " << frame_id;
    ++i;
  }

  const std::string stats = test::readText(dir / "optimiser_stats.json");
  EXPECT_NE(stats.find("\"loop_closures\": 1"), std::string::npos) << stats;
  EXPECT_NE(stats.find("\"loop_edges_removed\": 0"), std::string::npos) << stats;
  EXPECT_NE(stats.find("\"keyframes\": 40"), std::string::npos) << stats;
  // The NaN information is rejected on arrival; the edge to keyframe 999 is
  // held for a keyframe that may still come (the service's restart
  // recovery) and left out, with a logged error, at the end.
  EXPECT_NE(stats.find("\"rejected_messages\": 1"), std::string::npos) << "the NaN constraint\n" << stats;
  EXPECT_NE(test::readText(dir / "optimiser.log").find("1 constraints name a keyframe that never arrived"), std::string::npos)
      << test::readText(dir / "optimiser.log");
}

}  // namespace
}  // namespace rekon::optimiser
