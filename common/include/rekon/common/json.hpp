#pragma once
// A small JSON object writer for stats.json and `--json` outputs (keys in
// insertion order), and reading a flat or nested JSON file back.
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace rekon {

class JsonObject {
 public:
  JsonObject& set(const std::string& key, double value);
  JsonObject& set(const std::string& key, long long value);
  JsonObject& set(const std::string& key, int value) { return set(key, static_cast<long long>(value)); }
  JsonObject& set(const std::string& key, long value) { return set(key, static_cast<long long>(value)); }
  JsonObject& set(const std::string& key, size_t value) { return set(key, static_cast<long long>(value)); }
  JsonObject& set(const std::string& key, bool value);
  JsonObject& set(const std::string& key, const std::string& value);
  JsonObject& set(const std::string& key, const char* value) { return set(key, std::string(value)); }
  JsonObject& set(const std::string& key, const JsonObject& value);
  // A value already in JSON form (a number, or an object read from a file).
  JsonObject& setRaw(const std::string& key, const std::string& json);

  bool empty() const { return fields_.empty(); }
  std::string str(int indent = 2) const;
  void save(const std::string& path) const;

 private:
  std::string str(int indent, int depth) const;
  std::vector<std::pair<std::string, std::string>> fields_;  // key -> JSON text
};

// A string as a JSON string literal (quoted and escaped).
std::string jsonString(const std::string& s);

// "key=value key=value" line of a flat object's numbers and strings (the last
// line that rekon's tools print).
std::string keyValueLine(const std::vector<std::pair<std::string, double>>& values);

}  // namespace rekon
