#include "rekon/common/mesh.hpp"

#include <cstring>
#include <fstream>
#include <sstream>

#include "rekon/common/error.hpp"
#include "rekon/common/files.hpp"

namespace rekon {

// Written beside and renamed (writeFileAtomically): a process killed while
// it writes leaves the previous mesh, never half of one.
void writePly(const Mesh& mesh, const std::string& path) {
  const bool colored = mesh.colors.size() == mesh.vertices.size() && !mesh.vertices.empty();
  std::ostringstream header;
  header << "ply\nformat binary_little_endian 1.0\ncomment rekon\nelement vertex " << mesh.vertices.size()
         << "\nproperty float x\nproperty float y\nproperty float z\n";
  if (colored) header << "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  header << "element face " << mesh.triangles.size() << "\nproperty list uchar int vertex_indices\nend_header\n";
  const std::string head = header.str();
  std::vector<char> buf(head.begin(), head.end());
  buf.reserve(head.size() + mesh.vertices.size() * 15 + mesh.triangles.size() * 13);
  auto put = [&buf](const void* p, size_t n) { buf.insert(buf.end(), static_cast<const char*>(p), static_cast<const char*>(p) + n); };
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    put(mesh.vertices[i].data(), 12);
    if (colored) put(mesh.colors[i].data(), 3);
  }
  for (const auto& t : mesh.triangles) {
    const uint8_t n = 3;
    put(&n, 1);
    put(t.data(), 12);
  }
  writeFileAtomically(path, std::string_view(buf.data(), buf.size()));
}

namespace {

struct Property {
  std::string name, type, list_count_type;
  bool is_list = false;
};
struct Element {
  std::string name;
  size_t count = 0;
  std::vector<Property> properties;
};

size_t typeSize(const std::string& t, const std::string& path) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" || t == "float32") return 4;
  if (t == "double" || t == "float64") return 8;
  throw Error(path + ": unknown PLY property type '" + t + "'");
}

double readBinary(const char*& p, const char* end, const std::string& t, const std::string& path) {
  const size_t n = typeSize(t, path);
  if (p + n > end) throw Error(path + ": PLY data is truncated; re-export the mesh");
  double v = 0;
  if (t == "char" || t == "int8") v = *reinterpret_cast<const int8_t*>(p);
  else if (t == "uchar" || t == "uint8") v = *reinterpret_cast<const uint8_t*>(p);
  else if (t == "short" || t == "int16") { int16_t x; std::memcpy(&x, p, 2); v = x; }
  else if (t == "ushort" || t == "uint16") { uint16_t x; std::memcpy(&x, p, 2); v = x; }
  else if (t == "int" || t == "int32") { int32_t x; std::memcpy(&x, p, 4); v = x; }
  else if (t == "uint" || t == "uint32") { uint32_t x; std::memcpy(&x, p, 4); v = x; }
  else if (t == "float" || t == "float32") { float x; std::memcpy(&x, p, 4); v = x; }
  else { double x; std::memcpy(&x, p, 8); v = x; }
  p += n;
  return v;
}

// The header: the body's format and its elements with their properties.
struct PlyHeader {
  std::string format;
  std::vector<Element> elements;
};

PlyHeader readHeader(std::istream& in, const std::string& path) {
  std::string line;
  std::getline(in, line);
  if (line.rfind("ply", 0) != 0) throw Error(path + ": not a PLY file");
  PlyHeader header;
  auto& elements = header.elements;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream ss(line);
    std::string word;
    ss >> word;
    if (word == "format") ss >> header.format;
    else if (word == "element") {
      Element e;
      ss >> e.name >> e.count;
      elements.push_back(e);
    } else if (word == "property") {
      if (elements.empty()) throw Error(path + ": PLY property before any element");
      Property p;
      std::string t;
      ss >> t;
      if (t == "list") {
        p.is_list = true;
        ss >> p.list_count_type >> p.type >> p.name;
      } else {
        p.type = t;
        ss >> p.name;
      }
      elements.back().properties.push_back(p);
    } else if (word == "end_header") {
      break;
    }
  }
  if (header.format != "binary_little_endian" && header.format != "ascii") {
    throw Error(path + ": PLY format '" + header.format +
                "' is not supported; save as binary_little_endian or ascii");
  }
  return header;
}

// The body after the header, one value at a time: numbers in text for ASCII,
// little-endian values of each property's type for binary.
class PlyValues {
 public:
  PlyValues(std::istream& in, const std::string& format, const std::string& path)
      : path_(path),
        ascii_format_(format == "ascii"),
        body_((std::istreambuf_iterator<char>(in)), {}),
        p_(body_.data()),
        end_(p_ + body_.size()),
        ascii_(ascii_format_ ? body_ : std::string()) {}
  PlyValues(const PlyValues&) = delete;  // p_ and end_ point into body_
  PlyValues& operator=(const PlyValues&) = delete;

  double next(const std::string& type) {
    if (ascii_format_) {
      double v;
      if (!(ascii_ >> v)) throw Error(path_ + ": PLY data is truncated or not numeric");
      return v;
    }
    return readBinary(p_, end_, type, path_);
  }

 private:
  const std::string& path_;
  const bool ascii_format_;
  const std::string body_;
  const char* p_;
  const char* end_;
  std::istringstream ascii_;
};

// A list property: its values, and the triangles of a fan over them when it
// is a face's vertex indices.
void readList(const Property& prop, bool is_face, PlyValues& values, Mesh& mesh, const std::string& path) {
  const auto n = static_cast<long>(values.next(prop.list_count_type));
  if (n < 0 || n > 64) throw Error(path + ": PLY face with " + std::to_string(n) + " vertices");
  std::vector<int> idx(n);
  for (auto& x : idx) x = static_cast<int>(values.next(prop.type));
  if (is_face && (prop.name == "vertex_indices" || prop.name == "vertex_index")) {
    for (long k = 1; k + 1 < n; ++k) mesh.triangles.emplace_back(idx[0], idx[k], idx[k + 1]);
  }
}

// Every item of one element; vertices and faces go into the mesh, the
// values of anything else are read past.
void readElement(const Element& e, PlyValues& values, Mesh& mesh, const std::string& path) {
  const bool is_vertex = e.name == "vertex";
  const bool is_face = e.name == "face";
  if (is_vertex) mesh.vertices.reserve(e.count);
  bool has_color = false;
  for (const auto& prop : e.properties) has_color |= is_vertex && prop.name == "red";
  for (size_t i = 0; i < e.count; ++i) {
    Eigen::Vector3f v = Eigen::Vector3f::Zero();
    std::array<uint8_t, 3> c{0, 0, 0};
    for (const auto& prop : e.properties) {
      if (prop.is_list) {
        readList(prop, is_face, values, mesh, path);
        continue;
      }
      const double x = values.next(prop.type);
      if (!is_vertex) continue;
      if (prop.name == "x") v.x() = static_cast<float>(x);
      else if (prop.name == "y") v.y() = static_cast<float>(x);
      else if (prop.name == "z") v.z() = static_cast<float>(x);
      else if (prop.name == "red") c[0] = static_cast<uint8_t>(x);
      else if (prop.name == "green") c[1] = static_cast<uint8_t>(x);
      else if (prop.name == "blue") c[2] = static_cast<uint8_t>(x);
    }
    if (is_vertex) {
      mesh.vertices.push_back(v);
      if (has_color) mesh.colors.push_back(c);
    }
  }
}

void checkFaceIndices(const Mesh& mesh, const std::string& path) {
  for (const auto& t : mesh.triangles) {
    if ((t.array() < 0).any() || (t.array() >= static_cast<int>(mesh.vertices.size())).any()) {
      throw Error(path + ": a face refers to a vertex that does not exist; the mesh is corrupt");
    }
  }
}

}  // namespace

Mesh readPly(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error(path + ": cannot open mesh; check the path");
  const PlyHeader header = readHeader(in, path);
  PlyValues values(in, header.format, path);
  Mesh mesh;
  for (const auto& e : header.elements) readElement(e, values, mesh, path);
  checkFaceIndices(mesh, path);
  return mesh;
}

}  // namespace rekon
