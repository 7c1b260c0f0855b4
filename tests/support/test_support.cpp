#include "test_support.hpp"

#include <sys/wait.h>

#include <array>
#include <cstdio>
#include <cstdlib>
#include <filesystem>

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

}  // namespace rekon::test
