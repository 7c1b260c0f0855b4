#include "rekon/common/config.hpp"

#include <yaml-cpp/yaml.h>

#include <fstream>
#include <sstream>

#include "rekon/common/cli.hpp"
#include "rekon/common/error.hpp"

namespace rekon {
namespace {

const char* kFix = "see config/default.yaml for every key and its type";

// Every key under `node` (sections and values), as dotted paths after `prefix`.
void keyPaths(const YAML::Node& node, const std::string& prefix, std::vector<std::string>& out) {
  if (!node.IsMap()) return;
  for (const auto& kv : node) {
    const std::string key = (prefix.empty() ? "" : prefix + ".") + kv.first.as<std::string>();
    out.push_back(key);
    keyPaths(kv.second, key, out);
  }
}

// "; did you mean 'volume.voxel_size'?" for a mistyped key, or "".
std::string nearestKey(const YAML::Node& node, const std::string& prefix, const std::string& key) {
  std::vector<std::string> paths;
  keyPaths(node, prefix, paths);
  return didYouMean(key, paths);
}

std::vector<std::string> splitKey(const std::string& key) {
  std::vector<std::string> parts;
  std::stringstream ss(key);
  std::string p;
  while (std::getline(ss, p, '.')) parts.push_back(p);
  return parts;
}

// Lays `over` onto `base` (a clone of the defaults); every key of `over` must
// exist in `base` with the same kind of node.
void overlay(YAML::Node base, const YAML::Node& over, const std::string& prefix, const std::string& source) {
  if (!over.IsMap()) throw Error(source + ": " + (prefix.empty() ? "top level" : prefix) + " must be a mapping; " + kFix);
  for (const auto& kv : over) {
    // A sequence or mapping as a key (`? [a, b] : 1`) has no name to look up.
    if (!kv.first.IsScalar()) {
      throw Error(source + ": a key under " + (prefix.empty() ? "the top level" : "'" + prefix + "'") +
                  " is a list or mapping, not a name; " + kFix);
    }
    const std::string name = kv.first.as<std::string>();
    const std::string key = prefix.empty() ? name : prefix + "." + name;
    const YAML::Node existing = static_cast<const YAML::Node&>(base)[name];
    if (!existing) throw Error(source + ": unknown config key '" + key + "'" + nearestKey(base, prefix, key) + "; " + kFix);
    if (existing.IsMap()) {
      overlay(base[name], kv.second, key, source);
    } else if (kv.second.IsMap()) {
      throw Error(source + ": config key '" + key + "' is a value, not a section; " + kFix);
    } else {
      base[name] = YAML::Clone(kv.second);
    }
  }
}

YAML::Node parse(const std::string& text, const std::string& source) {
  try {
    return YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw Error(source + ": invalid YAML at line " + std::to_string(e.mark.line + 1) + " (" + e.msg + "); fix the file");
  }
}

}  // namespace

Config::Config() : root_(std::make_unique<YAML::Node>(parse(defaultConfigYaml(), "config/default.yaml"))) {}
Config::Config(const Config& other) : root_(std::make_unique<YAML::Node>(YAML::Clone(*other.root_))) {}
Config& Config::operator=(const Config& other) {
  root_ = std::make_unique<YAML::Node>(YAML::Clone(*other.root_));
  return *this;
}
Config::~Config() = default;

Config Config::fromYamlText(const std::string& yaml_text, const std::vector<std::string>& sets) {
  Config c;
  const YAML::Node over = parse(yaml_text, "config");
  if (over.IsDefined() && !over.IsNull()) overlay(*c.root_, over, "", "config");
  for (const auto& s : sets) {
    const auto eq = s.find('=');
    if (eq == std::string::npos || eq == 0) throw Error("--set " + s + ": expected key=value, for example --set volume.voxel_size=0.02");
    c.set(s.substr(0, eq), s.substr(eq + 1));
  }
  return c;
}

Config Config::load(const std::string& file, const std::vector<std::string>& sets) {
  std::string text;
  if (!file.empty()) {
    std::ifstream in(file);
    if (!in) throw Error(file + ": cannot read config file; check the --config path");
    std::stringstream ss;
    ss << in.rdbuf();
    text = ss.str();
  }
  try {
    return fromYamlText(text, sets);
  } catch (const Error& e) {
    const std::string msg = e.what();
    // Name the user's file instead of the generic "config".
    if (!file.empty() && msg.rfind("config:", 0) == 0) throw Error(file + msg.substr(6));
    throw;
  }
}

YAML::Node Config::node(const std::string& key) const {
  YAML::Node n;
  n.reset(*root_);
  for (const auto& part : splitKey(key)) {
    const YAML::Node& cn = n;
    if (!cn.IsMap() || !cn[part]) throw Error("config key '" + key + "' does not exist; " + kFix);
    n.reset(cn[part]);
  }
  return n;
}

void Config::set(const std::string& key, const std::string& value) {
  const auto parts = splitKey(key);
  if (parts.empty()) throw Error("--set: empty key; " + std::string(kFix));
  YAML::Node n;
  n.reset(*root_);
  for (size_t i = 0; i < parts.size(); ++i) {
    const YAML::Node& cn = n;
    if (!cn.IsMap() || !cn[parts[i]])
      throw Error("--set " + key + ": unknown config key" + nearestKey(*root_, "", key) + "; " + kFix);
    if (i + 1 < parts.size()) n.reset(cn[parts[i]]);
  }
  const YAML::Node& parent = n;
  if (parent[parts.back()].IsMap()) throw Error("--set " + key + ": is a section, not a value; " + kFix);
  n[parts.back()] = parse(value, "--set " + key);
}

#define REKON_CONFIG_GET(Type, Name, Expect)                                                                 \
  Type Config::Name(const std::string& key) const {                                                         \
    const YAML::Node n = node(key);                                                                         \
    try {                                                                                                   \
      return n.as<Type>();                                                                                  \
    } catch (const YAML::Exception&) {                                                                      \
      throw Error("config key '" + key + "' must be " + Expect + "; " + kFix);                              \
    }                                                                                                       \
  }
REKON_CONFIG_GET(double, getDouble, "a number")
REKON_CONFIG_GET(int, getInt, "an integer")
REKON_CONFIG_GET(bool, getBool, "true or false")
REKON_CONFIG_GET(std::string, getString, "a string")
REKON_CONFIG_GET(std::vector<std::string>, getStringList, "a list of strings")
#undef REKON_CONFIG_GET

std::string Config::dump() const {
  YAML::Emitter out;
  out << *root_;
  return std::string(out.c_str()) + "\n";
}

void Config::save(const std::string& path) const {
  std::ofstream out(path);
  out << dump();
  if (!out) throw Error(path + ": cannot write config; check the output folder");
}

}  // namespace rekon
