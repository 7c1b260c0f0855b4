#include "rekon/common/json.hpp"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "rekon/common/error.hpp"
#include "rekon/common/files.hpp"

namespace rekon {
namespace {

std::string number(double v) {
  if (!std::isfinite(v)) return "null";  // JSON has no NaN; readers see a missing value
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.9g", v);
  return buf;
}

}  // namespace

std::string jsonString(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    switch (c) {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\n': out += "\\n"; break;
      case '\t': out += "\\t"; break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          char buf[8];
          std::snprintf(buf, sizeof(buf), "\\u%04x", c);
          out += buf;
        } else {
          out += c;
        }
    }
  }
  return out + "\"";
}

JsonObject& JsonObject::set(const std::string& key, double value) { return setRaw(key, number(value)); }
JsonObject& JsonObject::set(const std::string& key, long long value) { return setRaw(key, std::to_string(value)); }
JsonObject& JsonObject::set(const std::string& key, bool value) { return setRaw(key, value ? "true" : "false"); }
JsonObject& JsonObject::set(const std::string& key, const std::string& value) { return setRaw(key, jsonString(value)); }
JsonObject& JsonObject::set(const std::string& key, const JsonObject& value) { return setRaw(key, value.str(0, 0)); }

JsonObject& JsonObject::setRaw(const std::string& key, const std::string& json) {
  for (auto& f : fields_) {
    if (f.first == key) {
      f.second = json;
      return *this;
    }
  }
  fields_.emplace_back(key, json);
  return *this;
}

std::string JsonObject::str(int indent) const { return str(indent, 0); }

std::string JsonObject::str(int indent, int depth) const {
  if (fields_.empty()) return "{}";
  const std::string nl = indent > 0 ? "\n" : "";
  const std::string pad(static_cast<size_t>(indent * (depth + 1)), ' ');
  const std::string close_pad(static_cast<size_t>(indent * depth), ' ');
  std::ostringstream out;
  out << "{" << nl;
  for (size_t i = 0; i < fields_.size(); ++i) {
    out << pad << jsonString(fields_[i].first) << (indent > 0 ? ": " : ":") << fields_[i].second;
    out << (i + 1 < fields_.size() ? "," : "") << nl;
  }
  out << close_pad << "}";
  return out.str();
}

void JsonObject::save(const std::string& path) const { writeFileAtomically(path, str() + "\n"); }

std::string keyValueLine(const std::vector<std::pair<std::string, double>>& values) {
  std::string line;
  for (const auto& [k, v] : values) {
    if (!line.empty()) line += ' ';
    line += k + "=" + number(v);
  }
  return line;
}

}  // namespace rekon
