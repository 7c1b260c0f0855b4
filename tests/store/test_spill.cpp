// The keyframe store's capacity policy: a full segment spills keyframes to
// files, farthest from the camera first, and reads them back on demand; bad
// spill files and folders are one-line errors.
#include <gtest/gtest.h>
#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <functional>
#include <fstream>
#include <opencv2/core.hpp>

#include "rekon/common/error.hpp"
#include "rekon/mapper/store/keyframe_store.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;
using namespace rekon;
using rekon::store::KeyframeStore;
using rekon::store::StoreOptions;

namespace {

// 160x120 keyframes take 160*120*11 = 211200 bytes: a 1 MiB segment holds 4
// (844800 bytes and the index), never 5 (1056000 > 1048576).
constexpr int kWidth = 160, kHeight = 120;
constexpr size_t kResidentIn1MiB = 4;

Intrinsics camera() {
  Intrinsics k;
  k.width = kWidth;
  k.height = kHeight;
  k.fx = k.fy = 131.25;
  k.cx = 79.5;
  k.cy = 59.5;
  return k;
}

// Keyframe `id` anchored at DVO keyframe `id`, with images no other id has.
fusion::FusedKeyframe keyframe(int64_t id) {
  fusion::FusedKeyframe kf;
  kf.id = id;
  kf.anchor_keyframe_id = id;
  kf.first_frame_id = 20 * id;
  kf.last_frame_id = 20 * id + 19;
  kf.frames = 20;
  kf.timestamp = id / 1.5;
  kf.depth = cv::Mat(kHeight, kWidth, CV_32F);
  kf.weight = cv::Mat(kHeight, kWidth, CV_32F);
  kf.color = cv::Mat(kHeight, kWidth, CV_8UC3);
  cv::RNG rng(static_cast<uint64_t>(id) + 1);
  rng.fill(kf.depth, cv::RNG::UNIFORM, 0.5, 4.0);
  rng.fill(kf.weight, cv::RNG::UNIFORM, 0.0, 20.0);
  rng.fill(kf.color, cv::RNG::UNIFORM, 0, 256);
  return kf;
}

bool sameImages(const fusion::FusedKeyframe& a, const fusion::FusedKeyframe& b) {
  return a.id == b.id && a.anchor_keyframe_id == b.anchor_keyframe_id && a.first_frame_id == b.first_frame_id &&
         a.last_frame_id == b.last_frame_id && a.frames == b.frames && a.timestamp == b.timestamp &&
         cv::norm(a.depth, b.depth, cv::NORM_INF) == 0 && cv::norm(a.weight, b.weight, cv::NORM_INF) == 0 &&
         cv::norm(a.color, b.color, cv::NORM_INF) == 0;
}

Pose at(double x) {
  Pose p = Pose::Identity();
  p.translation() = Eigen::Vector3d(x, 0, 0);
  return p;
}

// A 1 MiB store spilling into its own folder, removed at the end.
struct SpillingStore {
  test::TempDir dir;
  StoreOptions options;
  std::unique_ptr<KeyframeStore> store;
  explicit SpillingStore(const std::string& tag, const std::string& spill = "") {
    options.segment = "rekon_test_spill_" + tag + "_" + std::to_string(getpid());
    options.size_mb = 1;
    options.spill_dir = spill.empty() ? dir / "spill" : spill;
    KeyframeStore::remove(options.segment);
    store = KeyframeStore::openOrCreate(options, camera());
  }
  ~SpillingStore() {
    store.reset();
    KeyframeStore::remove(options.segment);
  }
  // As the mapper does: the anchor's pose first, then the keyframe.
  void add(int64_t id, double x) {
    store->setAnchorPose(id, at(x));
    store->add(keyframe(id));
  }
  std::string file(int64_t id) const { return options.spill_dir + "/" + options.segment + "_kf_" + std::to_string(id) + ".rks"; }
  std::vector<int64_t> spilledIds() const {
    std::vector<int64_t> ids;
    for (const auto& i : store->list())
      if (i.spilled) ids.push_back(i.id);
    return ids;
  }
};

std::string errorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

}  // namespace

TEST(KeyframeStoreSpill, AFullStoreSpillsAndKeepsEveryKeyframe) {
  SpillingStore s("all");
  for (int id = 0; id < 10; ++id) s.add(id, id);  // walking along x, one metre a keyframe
  const store::StoreUsage u = s.store->usage();
  EXPECT_EQ(u.keyframes, 10u);
  EXPECT_EQ(u.resident, kResidentIn1MiB);
  EXPECT_EQ(u.spilled, 10u - kResidentIn1MiB);
  EXPECT_EQ(u.spilled_bytes, (10u - kResidentIn1MiB) * (211200u + 48u));  // payload and the 48-byte file header
  for (size_t i = 0; i < 10; ++i) EXPECT_TRUE(sameImages(s.store->load(i), keyframe(static_cast<int64_t>(i)))) << i;
  EXPECT_TRUE(sameImages(s.store->loadById(2), keyframe(2)));
}

TEST(KeyframeStoreSpill, TheKeyframesFarthestFromTheCameraSpillFirst) {
  SpillingStore s("far");
  // Out to x = 4 and back: coming back, the far end is spilled, not the oldest keyframes near the camera.
  const double xs[] = {0, 1, 2, 3, 4, 3, 2};
  for (int id = 0; id < 7; ++id) s.add(id, xs[id]);
  // id 4 (x 4) spills 0 (4 m away); id 5 (x 3) spills 1 (2 m); id 6 (x 2) spills 4 (2 m, farther than 3 and 5 at 1 m).
  EXPECT_EQ(s.spilledIds(), (std::vector<int64_t>{0, 1, 4}));
}

TEST(KeyframeStoreSpill, OtherProcessesAndARestartSeeSpilledKeyframes) {
  SpillingStore s("reopen");
  for (int id = 0; id < 8; ++id) s.add(id, id);
  const auto reader = KeyframeStore::openExisting(s.options.segment);  // as `rekon keyframes` opens it
  ASSERT_EQ(reader->size(), 8u);
  for (size_t i = 0; i < 8; ++i) EXPECT_TRUE(sameImages(reader->load(i), keyframe(static_cast<int64_t>(i)))) << i;
  s.store.reset();  // the mapper stops; a restarted one opens the same segment
  StoreOptions other = s.options;
  other.spill_dir = s.dir / "elsewhere";  // ignored: the segment keeps the folder its keyframes are in
  const auto restarted = KeyframeStore::openOrCreate(other, camera());
  EXPECT_EQ(restarted->usage().spill_dir, s.options.spill_dir);
  for (size_t i = 0; i < 8; ++i) EXPECT_TRUE(sameImages(restarted->load(i), keyframe(static_cast<int64_t>(i)))) << i;
  restarted->add(keyframe(8));  // and it keeps spilling
  EXPECT_EQ(restarted->usage().spilled, 9u - kResidentIn1MiB);
}

TEST(KeyframeStoreSpill, RekonKeyframesExportsSpilledKeyframes) {
  SpillingStore s("export");
  for (int id = 0; id < 6; ++id) s.add(id, id);
  std::string out;
  const std::string cmd = test::binDir() + "/rekon keyframes --list --export " + (s.dir / "export") + " --segment " + s.options.segment;
  ASSERT_EQ(test::runCommand(cmd, &out), 0) << out;
  EXPECT_NE(out.find("6 keyframes, 4 in shared memory"), std::string::npos) << out;
  EXPECT_NE(out.find("2 spilled"), std::string::npos) << out;
  for (int id = 0; id < 6; ++id)
    EXPECT_TRUE(fs::exists(s.dir / ("export/kf_00000" + std::to_string(id) + "_depth.png"))) << id;
}

// A process killed while it holds the store's lock leaves the store usable
// (a restarted mapper must not find it locked for good). The holder here is
// `rekon keyframes --export` reading a spilled keyframe whose file was
// swapped for a FIFO: it waits inside the lock until the FIFO gets data,
// and is killed there. Then every keyframe reads back and adding still
// allocates and spills.
TEST(KeyframeStoreSpill, AReaderKilledInsideTheLockLeavesTheStoreUsable) {
  SpillingStore s("killed");
  for (int id = 0; id < 6; ++id) s.add(id, id);
  const std::string file = s.file(s.spilledIds().front()), aside = file + ".aside";
  fs::rename(file, aside);
  ASSERT_EQ(mkfifo(file.c_str(), 0600), 0);
  const std::string tool = test::binDir() + "/rekon";
  const std::string export_dir = s.dir / "export";
  const char* argv[] = {tool.c_str(), "keyframes", "--export", export_dir.c_str(), "--segment", s.options.segment.c_str(), nullptr};
  pid_t reader = 0;
  ASSERT_EQ(posix_spawn(&reader, tool.c_str(), nullptr, nullptr, const_cast<char* const*>(argv), environ), 0);
  // A FIFO opens for writing without blocking only once a reader has it
  // open: then the reader is inside load(), inside the lock, waiting for data.
  int fifo = -1;
  for (int i = 0; i < 6000 && fifo < 0; ++i) {  // 60 s: the tool started in 0.1 s here
    fifo = open(file.c_str(), O_WRONLY | O_NONBLOCK);
    if (fifo < 0) usleep(10000);
  }
  ASSERT_GE(fifo, 0) << "rekon keyframes never opened the spill file";
  ASSERT_EQ(kill(reader, SIGKILL), 0);
  int status = 0;
  ASSERT_EQ(waitpid(reader, &status, 0), reader);
  ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL) << status;
  close(fifo);
  fs::remove(file);
  fs::rename(aside, file);
  ASSERT_EQ(s.store->size(), 6u);
  for (size_t i = 0; i < 6; ++i) EXPECT_TRUE(sameImages(s.store->load(i), keyframe(static_cast<int64_t>(i)))) << i;
  s.add(6, 6);
  EXPECT_EQ(s.store->usage().spilled, 7u - kResidentIn1MiB);
  EXPECT_TRUE(sameImages(s.store->loadById(6), keyframe(6)));
}

TEST(KeyframeStoreSpill, RemovingTheStoreRemovesItsSpillFiles) {
  SpillingStore s("remove");
  for (int id = 0; id < 6; ++id) s.add(id, id);
  std::ofstream(s.dir / "spill/not_ours.txt") << "a user's file in the same folder\n";
  ASSERT_TRUE(fs::exists(s.file(0)));
  s.store.reset();
  EXPECT_TRUE(KeyframeStore::remove(s.options.segment));
  size_t left = 0;
  for (const auto& e : fs::directory_iterator(s.dir / "spill")) left += e.path().filename() != "not_ours.txt";
  EXPECT_EQ(left, 0u);
  EXPECT_TRUE(fs::exists(s.dir / "spill/not_ours.txt"));
}

TEST(KeyframeStoreSpill, TheAutomaticFolderIsNamedAfterTheSegmentAndRemovedWithIt) {
  test::TempDir tmp;
  setenv("TMPDIR", tmp.path().c_str(), 1);
  SpillingStore s("auto", StoreOptions::kAutoSpillDir);
  for (int id = 0; id < 6; ++id) s.add(id, id);
  const std::string dir = tmp / (s.options.segment + ".spill");
  EXPECT_EQ(s.store->usage().spill_dir, dir);
  EXPECT_TRUE(fs::exists(dir + "/" + s.options.segment + "_kf_0.rks"));
  s.store.reset();
  KeyframeStore::remove(s.options.segment);
  EXPECT_FALSE(fs::exists(dir));
  unsetenv("TMPDIR");
}

TEST(KeyframeStoreSpill, WithSpillingOffAFullStoreIsAnErrorNamingTheSettings) {
  SpillingStore s("off", StoreOptions::kNoSpilling);
  for (int id = 0; id < 4; ++id) s.add(id, id);
  const std::string e = errorOf([&] { s.add(4, 4); });
  EXPECT_NE(e.find("mapper.store_mb"), std::string::npos) << e;
  EXPECT_NE(e.find("mapper.store_spill_dir"), std::string::npos) << e;
  EXPECT_EQ(s.store->size(), 4u);
}

TEST(KeyframeStoreSpill, AKeyframeLargerThanTheSegmentIsAnError) {
  test::TempDir dir;
  StoreOptions o;
  o.segment = "rekon_test_spill_big_" + std::to_string(getpid());
  o.size_mb = 1;
  o.spill_dir = dir / "spill";
  KeyframeStore::remove(o.segment);
  Intrinsics big = camera();
  big.width = 640;  // 640x480: 3.3 MiB
  big.height = 480;
  auto store = KeyframeStore::openOrCreate(o, big);
  fusion::FusedKeyframe kf = keyframe(0);
  kf.depth = cv::Mat(480, 640, CV_32F, cv::Scalar(1.0f));
  kf.weight = cv::Mat(480, 640, CV_32F, cv::Scalar(1.0f));
  kf.color = cv::Mat(480, 640, CV_8UC3, cv::Scalar(50, 100, 150));
  const std::string e = errorOf([&] { store->add(kf); });
  EXPECT_NE(e.find("even with every other keyframe spilled; raise mapper.store_mb"), std::string::npos) << e;
  store.reset();
  KeyframeStore::remove(o.segment);
}

TEST(KeyframeStoreSpill, CorruptTruncatedOrMissingSpillFilesAreOneLineErrors) {
  SpillingStore s("corrupt");
  for (int id = 0; id < 7; ++id) s.add(id, id);  // 0, 1, 2 spilled
  {
    std::fstream f(s.file(0), std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(1000);
    f.put('\x5a');  // a flipped payload byte
  }
  fs::resize_file(s.file(1), 5000);
  fs::remove(s.file(2));
  const std::string corrupt = errorOf([&] { s.store->load(0); });
  const std::string truncated = errorOf([&] { s.store->load(1); });
  const std::string missing = errorOf([&] { s.store->load(2); });
  EXPECT_NE(corrupt.find("is corrupt (checksum mismatch)"), std::string::npos) << corrupt;
  EXPECT_NE(truncated.find("is truncated (5000 of 211248 bytes)"), std::string::npos) << truncated;
  EXPECT_NE(missing.find("cannot be opened (No such file or directory)"), std::string::npos) << missing;
  for (const std::string& e : {corrupt, truncated, missing}) {
    EXPECT_EQ(e.find('\n'), std::string::npos) << e;
    EXPECT_NE(e.find("rekon keyframes --remove"), std::string::npos) << e;
  }
  EXPECT_TRUE(sameImages(s.store->load(3), keyframe(3)));  // the rest is unharmed
}

TEST(KeyframeStoreSpill, ARestartWithItsSpillFolderGoneIsAnError) {
  SpillingStore s("gone");
  for (int id = 0; id < 6; ++id) s.add(id, id);
  s.store.reset();
  fs::remove_all(s.options.spill_dir);
  const std::string e = errorOf([&] { KeyframeStore::openOrCreate(s.options, camera()); });
  EXPECT_NE(e.find("has 2 keyframes spilled to " + s.options.spill_dir + ", which is missing"), std::string::npos) << e;
}

TEST(KeyframeStoreSpill, ASpillFolderThatCannotBeCreatedIsAnError) {
  test::TempDir dir;
  std::ofstream(dir / "file") << "a file, not a folder\n";
  StoreOptions o;
  o.segment = "rekon_test_spill_nodir_" + std::to_string(getpid());
  o.spill_dir = dir / "file/spill";
  KeyframeStore::remove(o.segment);
  const std::string e = errorOf([&] { KeyframeStore::openOrCreate(o, camera()); });
  EXPECT_NE(e.find("keyframe spill folder " + o.spill_dir + " cannot be created"), std::string::npos) << e;
  EXPECT_NE(e.find("mapper.store_spill_dir"), std::string::npos) << e;
  KeyframeStore::remove(o.segment);
}

TEST(KeyframeStoreSpill, AFullDiskIsAnErrorAndTheStoreKeepsWhatItHeld) {
  SpillingStore s("diskfull");
  for (int id = 0; id < 4; ++id) s.add(id, id);
  // A file size limit below one spill file stands in for a full disk (the write fails the same way).
  signal(SIGXFSZ, SIG_IGN);
  rlimit old{};
  getrlimit(RLIMIT_FSIZE, &old);
  rlimit small = old;
  small.rlim_cur = 100000;
  setrlimit(RLIMIT_FSIZE, &small);
  const std::string e = errorOf([&] { s.add(4, 4); });
  setrlimit(RLIMIT_FSIZE, &old);
  signal(SIGXFSZ, SIG_DFL);
  EXPECT_NE(e.find("cannot write keyframe spill file " + s.file(0) + " (write: File too large)"), std::string::npos) << e;
  EXPECT_EQ(s.store->size(), 4u);
  for (size_t i = 0; i < 4; ++i) EXPECT_TRUE(sameImages(s.store->load(i), keyframe(static_cast<int64_t>(i)))) << i;
  EXPECT_FALSE(fs::exists(s.file(0) + ".tmp"));
  s.add(4, 4);  // with room on disk again it goes on
  EXPECT_EQ(s.store->usage().spilled, 1u);
}
