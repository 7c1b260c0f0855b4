#pragma once
// rekon's configuration: config/default.yaml (compiled into every binary) is
// the schema and the defaults; a user file and `--set key=value` overrides are
// laid over it. An unknown key or a value of the wrong type is an error that
// names the key, never silently ignored. Each service reads its keys once into
// its own params struct.
#include <memory>
#include <string>
#include <vector>

namespace YAML {
class Node;
}

namespace rekon {

class Config {
 public:
  // Defaults, then `file` (may be empty), then each "dotted.key=value" in `sets`.
  static Config load(const std::string& file = "", const std::vector<std::string>& sets = {});
  // Defaults plus a YAML text laid over them (for tests and embedded use).
  static Config fromYamlText(const std::string& yaml_text, const std::vector<std::string>& sets = {});

  double getDouble(const std::string& key) const;
  int getInt(const std::string& key) const;
  bool getBool(const std::string& key) const;
  std::string getString(const std::string& key) const;
  std::vector<std::string> getStringList(const std::string& key) const;

  void set(const std::string& key, const std::string& value);
  // The effective configuration as YAML (written beside every run's outputs).
  std::string dump() const;
  void save(const std::string& path) const;

  Config(const Config& other);
  Config& operator=(const Config& other);
  ~Config();

 private:
  Config();
  YAML::Node node(const std::string& key) const;
  std::unique_ptr<YAML::Node> root_;
};

// The text of config/default.yaml, embedded at build time.
const char* defaultConfigYaml();

}  // namespace rekon
