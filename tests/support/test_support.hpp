#pragma once
// Helpers every rekon test uses: where the shared real data is, a fresh
// temporary folder, and running a built binary.
#include <gtest/gtest.h>

#include <sys/types.h>

#include <string>
#include <vector>

// 1 when malloc is glibc's: the sanitizers' allocators replace its heap, which
// tests of heap use (mallinfo2, RssAnon) measure (GCC says so with
// __SANITIZE_*__, clang with __has_feature).
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define REKON_GLIBC_HEAP 0
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define REKON_GLIBC_HEAP 0
#endif
#endif
#ifndef REKON_GLIBC_HEAP
#define REKON_GLIBC_HEAP 1
#endif

namespace rekon::test {

// ../shared/data/NAME, or "" when absent (REKON_DATA overrides the root).
std::string sharedDataset(const std::string& name);
// Skips the calling test with a visible message when the dataset is absent.
#define REKON_REQUIRE_DATASET(var, name)                                                      \
  const std::string var = ::rekon::test::sharedDataset(name);                                \
  if (var.empty()) GTEST_SKIP() << "../shared/data/" << (name) << " is absent: skipping (real-data test)"

// A new empty folder under the system temp dir, removed when the object dies,
// unless the test (or, for a suite's folder, the suite) it served has failed:
// then it is kept, with its service logs, stats and run.out, and its path is
// printed ("kept PATH for the failure's evidence"). REKON_KEEP_TEST_DIRS=1
// keeps every folder.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::string& path() const { return path_; }
  std::string operator/(const std::string& name) const { return path_ + "/" + name; }

 private:
  std::string path_;
};

std::string binDir();
std::string sourceDir();
// Runs a shell command, returns its exit status; stdout+stderr go to `output`.
int runCommand(const std::string& command, std::string* output = nullptr);

// Starts `/bin/sh -c command` in the background; its pid, or -1.
pid_t spawnShell(const std::string& command);
// Exit status of `pid` (128 + signal when killed by one), or -1 when it has
// not ended after `seconds`: it is then sent SIGTERM, and SIGKILL 5 s later.
int waitForExit(pid_t pid, double seconds);
// The whole text of a file ("" when it cannot be read).
std::string readText(const std::string& path);
// The integer after "key": in a flat JSON object (a service's stats), or -1.
long long jsonInt(const std::string& json, const std::string& key);
// The number after "key": in a JSON object, or NaN.
double jsonNumber(const std::string& json, const std::string& key);
// The shared-memory segments of a `rekon run` folder (frame ring, keyframe
// store, named in its config.yaml) still in /dev/shm.
std::vector<std::string> leftoverSegments(const std::string& run_dir);
// `--set` options that give a test's services a frame ring and a keyframe
// store of their own (named by `tag` and this process), for services started
// without `rekon run` (which appends its pid): tests run side by side, and
// rekon's default segment names would collide.
std::string ownSegments(const std::string& tag);

// tests/support/in_netns.sh: prefix a command with it to run it in a private
// network namespace (loopback multicast only).
std::string inNetns();
// The number after "key=" in a command's output (rekon eval prints
// `ate_rmse_m=...`), or -1 when it is absent.
double valueAfter(const std::string& text, const std::string& key);
// ATE RMSE (m) of a TUM trajectory against a ground truth (`rekon eval traj`), -1 when it fails.
double ateOf(const std::string& groundtruth, const std::string& trajectory);

// Multi-process tests whose own process talks on the bus: runs the current
// test again inside tests/support/in_netns.sh and reports its result; returns
// true only in that inner process, which then does the work.
//   TEST(X, Y) { if (!rekon::test::insideNetns()) return; ... }
bool insideNetns();

// Lines of `output` that look like a crash rather than a handled error
// (sanitizer reports, aborts, uncaught exceptions, decoder noise).
std::string crashLines(const std::string& output);

// A TCP socket listening on 127.0.0.1 at a port the system chose, for as long
// as it lives: a port that is in use.
class ListeningSocket {
 public:
  ListeningSocket();
  ~ListeningSocket();
  ListeningSocket(const ListeningSocket&) = delete;
  ListeningSocket& operator=(const ListeningSocket&) = delete;
  int port() const { return port_; }

 private:
  int fd_ = -1, port_ = 0;
};

}  // namespace rekon::test
