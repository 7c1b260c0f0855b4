// `rekon import bag ...` and `rekon spy`: commands whose work is done outside
// C++. The bag importer is Python (python/rekon/bag.py, rosbags in the project's
// .venv); lcm-spy is Java (build/java/rekon_msgs.jar holds rekon's types).
// Each is exec'd with the paths this build knows, so `rekon COMMAND` works from
// any folder; what is missing (no venv, no JDK, no jar) is one line naming the fix.
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <iostream>
#include <string>
#include <vector>

#include "commands.hpp"
#include "rekon/common/cli.hpp"
#include "rekon/common/config.hpp"
#include "rekon/common/error.hpp"

namespace rekon {
namespace fs = std::filesystem;
namespace {

std::string envOr(const char* name, const std::string& fallback) {
  const char* v = std::getenv(name);
  return v && *v ? v : fallback;
}

// The project's virtual environment (tools/rekon deps makes it).
std::string venvDir() { return envOr("REKON_VENV", std::string(REKON_SOURCE_DIR) + "/.venv"); }

// PYTHONPATH for the `rekon` Python package and the generated rekon_msgs types.
void exportPythonPath() {
  std::string path = std::string(REKON_SOURCE_DIR) + "/python:" + envOr("REKON_BUILD_DIR", REKON_BUILD_DIR) + "/python";
  if (const char* old = std::getenv("PYTHONPATH"); old && *old) path += std::string(":") + old;
  setenv("PYTHONPATH", path.c_str(), 1);
}

[[noreturn]] void execOrThrow(const std::vector<std::string>& args) {
  std::vector<char*> argv;
  for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  ::execvp(argv[0], argv.data());
  throw Error("cannot start " + args[0] + ": " + std::strerror(errno));
}

}  // namespace

int importCommand(int argc, char** argv) {
  const std::string what = argc > 1 ? argv[1] : "";
  if (what != "bag") {
    std::cerr << "usage: rekon import bag FILE --out DATASET | --list   (rekon import bag --help for the options)\n"
                 "  bag: a ROS 1 bag or a ROS 2 bag (sqlite3 or mcap) to a dataset folder for rekon run --dataset\n";
    return what == "--help" || what == "-h" ? 0 : 2;
  }
  const std::string python = venvDir() + "/bin/python";
  if (::access(python.c_str(), X_OK) != 0) {
    throw Error("reading bags needs the project's Python environment (" + venvDir() +
                ", with rosbags); make it with tools/rekon deps (it needs PyPI)");
  }
  exportPythonPath();
  std::vector<std::string> args = {python, "-m", "rekon.bag"};
  for (int i = 2; i < argc; ++i) args.emplace_back(argv[i]);
  execOrThrow(args);
}

int spyCommand(int argc, char** argv) {
  ArgParser args("rekon spy",
                 "lcm-spy on the run's bus with rekon's types (build/java/rekon_msgs.jar), so every channel is decoded. "
                 "Needs a display (X11 or a forwarded one).");
  args.option("config", "the run's config (its lcm.url)")
      .repeated("set", "key=value over the config (e.g. lcm.url=...)")
      .option("lcm-url", "the bus to watch (default: lcm.url of the config)")
      .examples("rekon spy\nrekon spy --lcm-url 'udpm://239.255.76.67:7667?ttl=1'");
  if (!args.parse(argc, argv)) return 0;
  const std::string url = args.has("lcm-url") ? args.get("lcm-url") : Config::load(args.get("config"), args.all("set")).getString("lcm.url");
  const std::string jar = envOr("REKON_BUILD_DIR", REKON_BUILD_DIR) + "/java/rekon_msgs.jar";
  if (!fs::exists(jar)) {
    throw Error(jar + " is missing: the build makes it when a JDK and lcm.jar are found (apt-get install "
                "default-jdk-headless liblcm-java, then tools/rekon setup)");
  }
  if (envOr("DISPLAY", "").empty() && envOr("WAYLAND_DISPLAY", "").empty()) {
    throw Error("lcm-spy is a window and there is no display (DISPLAY is not set): run rekon spy on a desktop or "
                "over ssh -X; without one, record the bus with lcm-logger and read it with the Python client "
                "(docs/python.md)");
  }
  // PyPI's lcm (in .venv) ships a lcm-spy that runs on Java 17; Debian 12's passes
  // the JVM option -Xincgc, which Java 17 refuses, so its jars are run directly.
  const std::string venv_spy = venvDir() + "/bin/lcm-spy";
  const std::string classpath = envOr("CLASSPATH", "");
  setenv("CLASSPATH", (jar + (classpath.empty() ? "" : ":" + classpath)).c_str(), 1);
  if (::access(venv_spy.c_str(), X_OK) == 0) execOrThrow({venv_spy, "--lcm-url=" + url});
  const std::string debian = "/usr/share/java/";
  for (const char* j : {"lcm.jar", "jchart2d.jar"}) {
    if (!fs::exists(debian + j)) {
      throw Error(std::string("no lcm-spy: neither ") + venv_spy + " (tools/rekon deps) nor " + debian + j +
                  " (apt-get install liblcm-java libjchart2d-java)");
    }
  }
  execOrThrow({"java", "-Djava.net.preferIPv4Stack=true", "-Xmx128m", "-cp",
               jar + ":" + debian + "lcm.jar:" + debian + "jchart2d.jar:" + debian + "jide-oss.jar:" + debian +
                   "xmlgraphics-commons.jar",
               "lcm.spy.Spy", "--lcm-url=" + url});
}

}  // namespace rekon
