#include "test_support.hpp"

#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <sstream>

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

TempDir::~TempDir() {
  if (std::getenv("REKON_KEEP_TEST_DIRS") == nullptr) {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
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

bool insideNetns() {
  static const char* kInside = "REKON_TEST_INSIDE_NETNS";
  if (std::getenv(kInside)) return true;
  const std::string in_netns = sourceDir() + "/tests/support/in_netns.sh";
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

}  // namespace rekon::test
