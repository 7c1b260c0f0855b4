#include "test_support.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cmath>
#include <regex>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

extern char** environ;

namespace rekon::test {
namespace fs = std::filesystem;

std::string sharedDataset(const std::string& name) {
  const char* env = std::getenv("REKON_DATA");
  const fs::path root = env ? fs::path(env) : fs::path(REKON_SHARED_DATA);
  const fs::path dir = root / name;
  return fs::is_directory(dir) ? fs::canonical(dir).string() : std::string();
}

TempDir::TempDir() {
  std::string tmpl = (fs::temp_directory_path() / "rekon_test_XXXXXX").string();
  if (!mkdtemp(tmpl.data())) throw std::runtime_error("mkdtemp failed");
  path_ = tmpl;
}

namespace {

// Whether what the folder served has failed so far: the running test, else
// (a suite's folder, removed in TearDownTestSuite) the running suite, else
// the whole program.
bool failedSoFar() {
  const auto* unit = ::testing::UnitTest::GetInstance();
  if (unit->current_test_info() != nullptr) return ::testing::Test::HasFailure();
  if (const auto* suite = unit->current_test_suite()) return suite->Failed();
  return unit->Failed();
}

}  // namespace

TempDir::~TempDir() {
  if (std::getenv("REKON_KEEP_TEST_DIRS") != nullptr) return;
  if (failedSoFar()) {
    std::fprintf(stderr, "kept %s for the failure's evidence\n", path_.c_str());
    return;
  }
  std::error_code ec;
  fs::remove_all(path_, ec);
}

std::string binDir() { return REKON_BIN_DIR; }
std::string sourceDir() { return REKON_SOURCE_DIR; }

int runCommand(const std::string& command, std::string* output) {
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  if (!pipe) return -1;
  std::array<char, 4096> buf{};
  std::string out;
  size_t n;
  while ((n = fread(buf.data(), 1, buf.size(), pipe)) > 0) out.append(buf.data(), n);
  const int status = pclose(pipe);
  if (output) *output = out;
  return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

pid_t spawnShell(const std::string& command) {
  const char* argv[] = {"/bin/sh", "-c", command.c_str(), nullptr};
  pid_t pid = -1;
  if (posix_spawn(&pid, "/bin/sh", nullptr, nullptr, const_cast<char**>(argv), environ) != 0) return -1;
  return pid;
}

int waitForExit(pid_t pid, double seconds) {
  using Clock = std::chrono::steady_clock;
  const auto status_of = [](int status) { return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status); };
  const auto end = Clock::now() + std::chrono::duration<double>(seconds);
  int status = 0;
  while (Clock::now() < end) {
    if (waitpid(pid, &status, WNOHANG) == pid) return status_of(status);
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  // SIGTERM first: `timeout` passes it on to the service it runs.
  kill(pid, SIGTERM);
  for (int i = 0; i < 250; ++i) {
    if (waitpid(pid, nullptr, WNOHANG) == pid) return -1;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  kill(pid, SIGKILL);
  waitpid(pid, nullptr, 0);
  return -1;
}

std::string readText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

long long jsonInt(const std::string& json, const std::string& key) {
  const auto at = json.find("\"" + key + "\":");
  if (at == std::string::npos) return -1;
  return std::stoll(json.substr(at + key.size() + 3));
}

double jsonNumber(const std::string& json, const std::string& key) {
  const auto at = json.find("\"" + key + "\":");
  if (at == std::string::npos) return std::nan("");
  try {
    return std::stod(json.substr(at + key.size() + 3));
  } catch (const std::exception&) {
    return std::nan("");
  }
}

std::string ownSegments(const std::string& tag) {
  const std::string id = tag + "_" + std::to_string(getpid());
  return " --set transport.segment=rekon_fr_" + id + " --set mapper.store_segment=rekon_kf_" + id;
}

std::vector<std::string> leftoverSegments(const std::string& run_dir) {
  std::vector<std::string> left;
  const std::string config = readText(run_dir + "/config.yaml");
  const std::regex seg(R"((?:^|\n)\s*(?:segment|store_segment):\s*"?([A-Za-z0-9_]+))");
  for (auto it = std::sregex_iterator(config.begin(), config.end(), seg); it != std::sregex_iterator(); ++it) {
    const std::string name = (*it)[1];
    if (std::filesystem::exists("/dev/shm/" + name)) left.push_back(name);
  }
  return left;
}

std::string inNetns() { return sourceDir() + "/tests/support/in_netns.sh"; }

double valueAfter(const std::string& text, const std::string& key) {
  const auto p = text.find(key + "=");
  if (p == std::string::npos) return -1.0;
  return std::stod(text.substr(p + key.size() + 1));
}

double ateOf(const std::string& groundtruth, const std::string& trajectory) {
  std::string out;
  runCommand(binDir() + "/rekon eval traj " + groundtruth + " " + trajectory, &out);
  return valueAfter(out, "ate_rmse_m");
}

bool insideNetns() {
  static const char* kInside = "REKON_TEST_INSIDE_NETNS";
  if (std::getenv(kInside)) return true;
  const std::string in_netns = inNetns();
  if (runCommand(in_netns + " true") != 0) {
    ADD_FAILURE() << "cannot create a network namespace (unshare -n); multi-process tests need root";
    return false;
  }
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const std::string filter = std::string(info->test_suite_name()) + "." + info->name();
  std::string out;
  const int rc = runCommand(std::string(kInside) + "=1 " + in_netns + " /proc/" + std::to_string(getpid()) +
                                "/exe --gtest_filter=" + filter,
                            &out);
  EXPECT_EQ(rc, 0) << out;
  return false;
}

std::string crashLines(const std::string& output) {
  static const char* kSigns[] = {"Sanitizer",     "runtime error:", "terminate called", "Segmentation fault",
                                 "Aborted",       "core dumped",    "libpng",           "Corrupt JPEG",
                                 "Premature end", "std::bad_alloc", "Assertion"};
  std::string found, line;
  std::istringstream in(output);
  while (std::getline(in, line)) {
    for (const char* sign : kSigns) {
      if (line.find(sign) != std::string::npos) {
        found += line + "\n";
        break;
      }
    }
  }
  return found;
}

ListeningSocket::ListeningSocket() : fd_(socket(AF_INET, SOCK_STREAM, 0)) {
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof a;
  if (fd_ < 0 || bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || listen(fd_, 1) != 0 ||
      getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &len) != 0) {
    ADD_FAILURE() << "cannot listen on a loopback port";
    return;
  }
  port_ = ntohs(a.sin_port);
}

ListeningSocket::~ListeningSocket() {
  if (fd_ >= 0) close(fd_);
}

}  // namespace rekon::test
