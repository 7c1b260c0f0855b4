// rekon-mapper as a process: rekon-player, rekon-replay (in place of tracker
// and optimiser) and rekon-mapper in a private network namespace on a small
// synthetic tabletop sequence.
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "rekon/store/keyframe_store.hpp"
#include "rekon/synth/synth.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;
using rekon::test::runCommand;

namespace {

std::string readText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// The integer after "key": in a flat JSON object, or -1.
long long jsonInt(const std::string& json, const std::string& key) {
  const auto at = json.find("\"" + key + "\":");
  if (at == std::string::npos) return -1;
  return std::stoll(json.substr(at + key.size() + 3));
}

}  // namespace

TEST(MapperService, ReplayedPosesAreCorrectedAndTheMeshWritten) {
  rekon::test::TempDir dir;
  rekon::synth::SequenceOptions o;
  o.scene = "tabletop";
  o.frames = 30;
  o.drift_translation_per_m = 0.05;
  o.drift_rotation_deg_per_m = 3.0;
  rekon::synth::writeSequence(o, dir / "data");
  const std::string bin = rekon::test::binDir(), id = std::to_string(getpid());
  const std::string seg = "rekon_mst_" + id, store = "rekon_mst_kf_" + id;
  const std::string script =
      bin + "/rekon-mapper --out " + (dir / "out") + " --set mapper.kappa=5 --set mapper.m=2 --set mapper.store_segment=" +
      store + " > " + (dir / "mapper.log") + " 2>&1 & m=$!; " + bin + "/rekon-replay --trajectory " +
      (dir / "data/drifted_trajectory.txt") + " --target " + (dir / "data/groundtruth.txt") + " --gap-ms 50 > " +
      (dir / "replay.log") + " 2>&1 & r=$!; " + bin + "/rekon-player --dataset " + (dir / "data") +
      " --set player.wait_for=[replay,mapper] --set transport.mode=shm --set transport.segment=" + seg + " > " +
      (dir / "player.log") + " 2>&1; p=$?; wait $r; rr=$?; wait $m; mm=$?; echo $p $rr $mm; [ $p$rr$mm = 000 ]";
  std::string out;
  const int rc = runCommand(rekon::test::sourceDir() + "/tests/support/in_netns.sh bash -c '" + script + "'", &out);
  ASSERT_EQ(rc, 0) << out << "\nmapper:\n" << readText(dir / "mapper.log") << "\nreplay:\n" << readText(dir / "replay.log");
  EXPECT_TRUE(fs::exists(dir / "out/mesh.ply"));
  const std::string stats = readText(dir / "out/mapper_stats.json");
  EXPECT_EQ(jsonInt(stats, "frames_fused"), 30);   // every frame has a replayed pose
  EXPECT_EQ(jsonInt(stats, "kf_keyframes"), 6);    // 30 frames / kappa 5
  EXPECT_EQ(jsonInt(stats, "integrations"), 6);
  EXPECT_EQ(jsonInt(stats, "deintegrations"), jsonInt(stats, "reintegrations"));
  EXPECT_GT(jsonInt(stats, "voxel_blocks"), 0);
  // A clean end removes the keyframe store.
  EXPECT_FALSE(fs::exists("/dev/shm/" + store));
}

TEST(MapperService, AKilledMapperRestartedWithResumeContinuesFromTheStore) {
  rekon::test::TempDir dir;
  rekon::synth::SequenceOptions o;
  o.scene = "tabletop";
  o.frames = 40;
  o.drift_translation_per_m = 0.05;
  o.drift_rotation_deg_per_m = 3.0;
  rekon::synth::writeSequence(o, dir / "data");
  const std::string bin = rekon::test::binDir(), id = std::to_string(getpid());
  const std::string store = "rekon_msr_kf_" + id;
  const std::string mapper = bin + "/rekon-mapper --out " + (dir / "out") +
                             " --set mapper.kappa=5 --set mapper.store_segment=" + store;
  const std::string replay = bin + "/rekon-replay --trajectory " + (dir / "data/drifted_trajectory.txt") + " --target " +
                             (dir / "data/groundtruth.txt");
  auto player = [&](int run, int frames) {
    return bin + "/rekon-player --dataset " + (dir / "data") + " --set player.max_frames=" + std::to_string(frames) +
           " --set player.wait_for=[replay,mapper] --set player.wait_timeout_s=3 --set transport.mode=shm" +
           " --set transport.segment=rekon_msr_" + id + "_" + std::to_string(run) + " > " +
           (dir / ("player" + std::to_string(run) + ".log")) + " 2>&1";
  };
  // Run 1: the mapper is killed (SIGKILL: no clean exit) once the store holds two keyframes; its
  // player then gives up waiting for acknowledgements. Run 2: a mapper with mapper.resume=true
  // rebuilds from the store and maps a new 10-frame stream on top.
  const std::string script =
      mapper + " > " + (dir / "mapper1.log") + " 2>&1 & m=$!; " + replay + " > " + (dir / "replay1.log") +
      " 2>&1 & r=$!; " + player(1, 40) + " & p=$!; " + "for i in $(seq 600); do [ $(" + bin +
      "/rekon keyframes --list --segment " + store + " 2>/dev/null | grep -c \"^ *[0-9]\") -ge 2 ] && break; sleep 0.05; done; " +
      "kill -9 $m; wait $m; wait $p; kill $r; wait $r; " + mapper + " --set mapper.resume=true > " + (dir / "mapper2.log") +
      " 2>&1 & m=$!; " + replay + " > " + (dir / "replay2.log") + " 2>&1 & r=$!; " + player(2, 10) +
      "; pp=$?; wait $r; rr=$?; wait $m; mm=$?; echo $pp $rr $mm; [ $pp$rr$mm = 000 ]";
  std::string out;
  const int rc = runCommand("timeout 120 " + rekon::test::sourceDir() + "/tests/support/in_netns.sh bash -c '" + script + "'", &out);
  rekon::store::KeyframeStore::remove(store);
  ASSERT_EQ(rc, 0) << out << "\nmapper1:\n" << readText(dir / "mapper1.log") << "\nmapper2:\n"
                   << readText(dir / "mapper2.log") << "\nplayer2:\n" << readText(dir / "player2.log");
  const std::string stats = readText(dir / "out/mapper_stats.json");
  EXPECT_GE(jsonInt(stats, "restored_keyframes"), 2);  // what the killed mapper had stored
  EXPECT_EQ(jsonInt(stats, "kf_keyframes"), 2);        // then the new stream: 10 frames / kappa 5
  EXPECT_TRUE(fs::exists(dir / "out/mesh.ply"));
  EXPECT_FALSE(fs::exists("/dev/shm/" + store));  // removed at the clean end
}
