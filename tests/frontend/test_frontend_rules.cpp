// The frontend contract's rules (messages/FRONTEND.md) on scripted bus
// traffic: a conforming frontend passes every rule, and each deliberately
// broken one fails exactly the rule it breaks, with a line naming the first
// offending message.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include "rekon/common/bus.hpp"
#include "rekon/common/messages.hpp"
#include "rekon/frontend_check/checker.hpp"
#include "rekon_msgs/constraint_t.hpp"
#include "rekon_msgs/done_t.hpp"
#include "rekon_msgs/frame_ack_t.hpp"
#include "rekon_msgs/frame_t.hpp"
#include "rekon_msgs/graph_update_t.hpp"
#include "rekon_msgs/keyframe_t.hpp"
#include "rekon_msgs/tracked_frame_t.hpp"

namespace {

using rekon::frontend_check::Checker;
using rekon::frontend_check::RuleResult;

struct Event {
  std::string channel;
  int64_t utime;
  std::string bytes;
};

template <class Msg>
Event event(const char* channel, int64_t utime, Msg msg) {
  msg.schema_version = rekon::kSchemaVersion;
  std::string bytes(static_cast<size_t>(msg.getEncodedSize()), '\0');
  msg.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  return {channel, utime, bytes};
}

rekon_msgs::pose_t poseAt(double x) {
  rekon_msgs::pose_t p{};
  p.t[0] = x;
  p.q[3] = 1.0;
  return p;
}

// What a conforming frontend sends for 20 frames, 20 ms apart: a keyframe
// every 5 frames (announced before its first tracked frame), the frame's
// acknowledgement 5 ms after it, an odometry constraint and a graph update
// holding every keyframe after each new keyframe, then the final update and
// done_t. Each part can be changed by a test to break one rule.
struct Script {
  static constexpr int kFrames = 20;
  static constexpr int kKeyframeEvery = 5;
  std::string ack_name = "tracker";
  std::function<void(rekon_msgs::tracked_frame_t&)> tracked = [](rekon_msgs::tracked_frame_t&) {};
  std::function<void(rekon_msgs::keyframe_t&)> keyframe = [](rekon_msgs::keyframe_t&) {};
  std::function<void(rekon_msgs::graph_update_t&)> update = [](rekon_msgs::graph_update_t&) {};
  std::function<void(std::vector<Event>&)> after = [](std::vector<Event>&) {};
  bool send_done = true;

  rekon_msgs::graph_update_t graphUpdate(int64_t version, int64_t keyframes) const {
    rekon_msgs::graph_update_t u{};
    u.version = version;
    for (int64_t k = 0; k < keyframes; ++k) {
      u.keyframe_ids.push_back(k);
      u.poses.push_back(poseAt(0.1 * static_cast<double>(k)));
    }
    update(u);
    u.num_keyframes = static_cast<int32_t>(u.keyframe_ids.size());
    return u;
  }

  std::vector<Event> events() const {
    std::vector<Event> out;
    int64_t keyframes = 0, version = 0;
    for (int64_t id = 0; id < kFrames; ++id) {
      const int64_t t = 20000 * id;
      rekon_msgs::frame_t f{};
      f.frame_id = id;
      out.push_back(event(rekon::channel::kFrames, t, f));
      if (id % kKeyframeEvery == 0) {
        rekon_msgs::keyframe_t kf{};
        kf.keyframe_id = keyframes++;
        kf.frame_id = id;
        kf.pose_world = poseAt(0.1 * static_cast<double>(kf.keyframe_id));
        keyframe(kf);
        out.push_back(event(rekon::channel::kKeyframes, t + 3000, kf));
      }
      rekon_msgs::tracked_frame_t tf{};
      tf.frame_id = id;
      tf.keyframe_id = keyframes - 1;
      tf.pose_in_keyframe = poseAt(0.02 * static_cast<double>(id % kKeyframeEvery));
      for (int i = 0; i < 6; ++i) tf.covariance[i * 7] = 1e-4;
      tracked(tf);
      out.push_back(event(rekon::channel::kTrackedFrames, t + 4000, tf));
      rekon_msgs::frame_ack_t ack{};
      ack.service = ack_name;
      ack.frame_id = id;
      out.push_back(event(rekon::channel::kFrameAck, t + 5000, ack));
      if (id % kKeyframeEvery == 0 && keyframes > 1) {
        rekon_msgs::constraint_t c{};
        c.kind = rekon_msgs::constraint_t::KIND_ODOMETRY;
        c.from_id = keyframes - 2;
        c.to_id = keyframes - 1;
        c.relative = poseAt(0.1);
        for (int i = 0; i < 6; ++i) c.information[i * 7] = 1e4;
        out.push_back(event(rekon::channel::kConstraints, t + 6000, c));
        out.push_back(event(rekon::channel::kGraphUpdates, t + 8000, graphUpdate(++version, keyframes)));
      }
    }
    const int64_t end = 20000 * kFrames;
    rekon_msgs::graph_update_t final_update = graphUpdate(++version, keyframes);
    final_update.final_update = true;
    for (int repeat = 0; repeat < 3; ++repeat)  // as the optimiser sends it: UDP may drop one
      out.push_back(event(rekon::channel::kGraphUpdates, end + 100 * repeat, final_update));
    rekon_msgs::done_t done{};
    done.service = "optimiser";
    if (send_done) out.push_back(event(rekon::channel::kDone, end + 1000, done));
    after(out);
    return out;
  }
};

std::vector<RuleResult> judge(const Script& script) {
  Checker checker;
  for (const Event& e : script.events()) checker.feed(e.channel, e.utime, e.bytes.data(), static_cast<int>(e.bytes.size()));
  return checker.judge();
}

// The ids of the failed rules, and their lines for the failure message.
std::vector<std::string> failedRules(const Script& script, std::string* lines) {
  std::vector<std::string> failed;
  for (const RuleResult& r : judge(script)) {
    *lines += rekon::frontend_check::formatResult(r) + "\n";
    if (!r.passed) failed.push_back(r.rule.id);
  }
  return failed;
}

void expectOnlyFails(const Script& script, const std::string& rule, const std::string& offence_words) {
  std::string lines;
  EXPECT_EQ(failedRules(script, &lines), std::vector<std::string>{rule}) << lines;
  EXPECT_NE(lines.find("FAIL " + rule + " "), std::string::npos) << lines;
  EXPECT_NE(lines.find(offence_words), std::string::npos) << lines;
}

}  // namespace

TEST(FrontendRules, AConformingFrontendPassesEveryRule) {
  std::string lines;
  EXPECT_TRUE(failedRules(Script{}, &lines).empty()) << lines;
  EXPECT_EQ(rekon::frontend_check::rules().size(), 11u);  // FC1..FC11 of messages/FRONTEND.md
}

TEST(FrontendRules, FC1AMessageThatDoesNotDecodeFails) {
  Script s;
  s.after = [](std::vector<Event>& events) {
    rekon_msgs::tracked_frame_t tf{};
    Event e = event(rekon::channel::kTrackedFrames, 1, tf);
    e.bytes.resize(e.bytes.size() / 2);  // truncated
    events.insert(events.begin() + 3, e);
  };
  expectOnlyFails(s, "FC1", "a message on TRACKED_FRAMES does not decode");
}

TEST(FrontendRules, FC1AnotherSchemaVersionFails) {
  Script s;
  s.after = [](std::vector<Event>& events) {
    rekon_msgs::keyframe_t kf{};
    kf.pose_world = poseAt(0);
    kf.schema_version = rekon::kSchemaVersion + 1;
    std::string bytes(static_cast<size_t>(kf.getEncodedSize()), '\0');
    kf.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
    events.push_back({rekon::channel::kKeyframes, 1, bytes});
  };
  expectOnlyFails(s, "FC1", "schema_version");
}

TEST(FrontendRules, FC2ATrackedFrameBeforeItsKeyframeFails) {
  Script s;
  // Keyframe 2's announcement comes after its first tracked frame (frame 10).
  s.after = [](std::vector<Event>& events) {
    for (size_t i = 0; i + 1 < events.size(); ++i) {
      if (events[i].channel == rekon::channel::kKeyframes && events[i + 1].channel == rekon::channel::kTrackedFrames &&
          events[i].utime == 20000 * 10 + 3000) {
        std::swap(events[i], events[i + 1]);
        return;
      }
    }
    FAIL() << "keyframe 2 not found in the script";
  };
  expectOnlyFails(s, "FC2", "tracked_frame_t 10 names keyframe 2 before any keyframe_t announced it");
}

TEST(FrontendRules, FC3AKeyframeAnnouncedTwiceFails) {
  Script s;
  s.after = [](std::vector<Event>& events) {
    for (const Event& e : events) {
      if (e.channel == rekon::channel::kKeyframes && e.utime == 20000 * 5 + 3000) {
        events.push_back(e);
        return;
      }
    }
  };
  expectOnlyFails(s, "FC3", "keyframe_t 1 was announced again");
}

TEST(FrontendRules, FC4ANonFinitePoseFails) {
  Script s;
  s.tracked = [](rekon_msgs::tracked_frame_t& tf) {
    if (tf.frame_id == 7) tf.pose_in_keyframe.t[1] = std::nan("");
  };
  expectOnlyFails(s, "FC4", "tracked_frame_t 7 has a non-finite pose");
}

TEST(FrontendRules, FC4ANonUnitQuaternionFails) {
  Script s;
  s.keyframe = [](rekon_msgs::keyframe_t& kf) {
    if (kf.keyframe_id == 3) kf.pose_world.q[3] = 0.5;
  };
  expectOnlyFails(s, "FC4", "keyframe_t 3 has a non-finite pose or a quaternion that is not unit");
}

TEST(FrontendRules, FC5AnAsymmetricCovarianceFails) {
  Script s;
  s.tracked = [](rekon_msgs::tracked_frame_t& tf) {
    if (tf.frame_id == 4) tf.covariance[1] = 1e-5;
  };
  expectOnlyFails(s, "FC5", "tracked_frame_t 4: its covariance is not symmetric");
}

TEST(FrontendRules, FC5ANegativeVarianceFails) {
  Script s;
  s.tracked = [](rekon_msgs::tracked_frame_t& tf) {
    if (tf.frame_id == 12) tf.covariance[14] = -1e-4;
  };
  expectOnlyFails(s, "FC5", "tracked_frame_t 12: its covariance is not positive semi-definite");
}

TEST(FrontendRules, FC6AVersionThatDoesNotIncreaseFails) {
  Script s;
  s.update = [](rekon_msgs::graph_update_t& u) {
    if (u.version == 3) u.version = 2;
  };
  expectOnlyFails(s, "FC6", "graph_update_t version 2 reuses version 2 with other content");
}

TEST(FrontendRules, FC6AVersionThatGoesBackFails) {
  Script s;
  s.update = [](rekon_msgs::graph_update_t& u) {
    if (u.version == 3) u.version = 1;
  };
  expectOnlyFails(s, "FC6", "graph_update_t version 1 goes back from version 2");
}

TEST(FrontendRules, FC6AnUpdateThatDropsAKeyframeFails) {
  Script s;
  s.update = [](rekon_msgs::graph_update_t& u) {
    if (u.version != 2) return;
    u.keyframe_ids.erase(u.keyframe_ids.begin() + 1);
    u.poses.erase(u.poses.begin() + 1);
  };
  expectOnlyFails(s, "FC6", "graph_update_t version 2 lacks keyframe 1, which version 1 held");
}

TEST(FrontendRules, FC7AFinalUpdateWithoutTheLastKeyframeFails) {
  Script s;
  s.update = [](rekon_msgs::graph_update_t& u) {
    if (u.keyframe_ids.size() < 4) return;  // keyframe 3 never in an update
    u.keyframe_ids.pop_back();
    u.poses.pop_back();
  };
  expectOnlyFails(s, "FC7", "the last graph update (version 4) lacks keyframe 3");
}

TEST(FrontendRules, FC8AcknowledgementsUnderAnotherNameFail) {
  Script s;
  s.ack_name = "my_slam";  // the player waits for "tracker"
  expectOnlyFails(s, "FC8", "frame 0 was never acknowledged as 'tracker'");
}

TEST(FrontendRules, FC9AFrameWithoutATrackedFrameFails) {
  Script s;
  s.after = [](std::vector<Event>& events) {
    for (auto it = events.begin(); it != events.end(); ++it) {
      if (it->channel == rekon::channel::kTrackedFrames && it->utime == 20000 * 13 + 4000) {
        events.erase(it);
        return;
      }
    }
  };
  expectOnlyFails(s, "FC9", "frame 13 got no tracked_frame_t");
}

TEST(FrontendRules, FC10NoDoneFails) {
  Script s;
  s.send_done = false;
  expectOnlyFails(s, "FC10", "no done_t{service: \"optimiser\"} arrived");
}

TEST(FrontendRules, FC10ATrackedFrameAfterDoneFails) {
  Script s;
  s.after = [](std::vector<Event>& events) {
    for (auto it = events.begin(); it != events.end(); ++it) {
      if (it->channel == rekon::channel::kTrackedFrames && it->utime == 20000 * 19 + 4000) {
        Event late = *it;
        late.utime = events.back().utime + 1000;
        events.erase(it);
        events.push_back(late);
        return;
      }
    }
  };
  expectOnlyFails(s, "FC10", "tracked_frame_t 19 arrived after done_t");
}

TEST(FrontendRules, FC11AFrameAnsweredTooLateFails) {
  Script s;
  // Frame 6 answered 1.5 s after it arrived (the bound is 1 s), still before done_t.
  s.after = [](std::vector<Event>& events) {
    for (Event& e : events) {
      if (e.channel == rekon::channel::kTrackedFrames && e.utime == 20000 * 6 + 4000) e.utime = 20000 * 6 + 1500000;
    }
  };
  expectOnlyFails(s, "FC11", "frame 6 was answered after 1500");
}
