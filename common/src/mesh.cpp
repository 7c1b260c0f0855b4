#include "rekon/common/mesh.hpp"

#include <cstring>
#include <fstream>
#include <sstream>

#include "rekon/common/error.hpp"
#include "rekon/common/files.hpp"

namespace rekon {

namespace {

std::string vertexPart(const std::string& path) { return path + ".vertices.tmp"; }
std::string facePart(const std::string& path) { return path + ".faces.tmp"; }

[[noreturn]] void cannotWrite(const std::string& path, const char* what) {
  throw Error("cannot write " + path + " (" + what + "); check the folder's permissions and free space");
}

// The binary little-endian format writePly and PlyWriter share: the header,
// then each vertex (xyz float, rgb uchar when colored), then each face.
std::string plyHeader(int64_t vertices, int64_t faces, bool colored) {
  std::ostringstream header;
  header << "ply\nformat binary_little_endian 1.0\ncomment rekon\nelement vertex " << vertices
         << "\nproperty float x\nproperty float y\nproperty float z\n";
  if (colored) header << "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  header << "element face " << faces << "\nproperty list uchar int vertex_indices\nend_header\n";
  return header.str();
}

void put(std::vector<char>& buf, const void* p, size_t n) {
  buf.insert(buf.end(), static_cast<const char*>(p), static_cast<const char*>(p) + n);
}

void appendVertices(std::vector<char>& buf, const Mesh& mesh, bool colored) {
  for (size_t i = 0; i < mesh.vertices.size(); ++i) {
    put(buf, mesh.vertices[i].data(), 12);
    if (colored) put(buf, mesh.colors[i].data(), 3);
  }
}

void appendFaces(std::vector<char>& buf, const Mesh& mesh) {
  for (const auto& t : mesh.triangles) {
    const uint8_t n = 3;
    put(buf, &n, 1);
    put(buf, t.data(), 12);
  }
}

}  // namespace

void appendMesh(Mesh& to, const Mesh& piece) {
  to.vertices.insert(to.vertices.end(), piece.vertices.begin(), piece.vertices.end());
  to.colors.insert(to.colors.end(), piece.colors.begin(), piece.colors.end());
  to.triangles.insert(to.triangles.end(), piece.triangles.begin(), piece.triangles.end());
}

// A mesh in memory: one buffer, written beside and renamed
// (writeFileAtomically), so a killed process leaves the previous file.
void writePly(const Mesh& mesh, const std::string& path) {
  const bool colored = mesh.colors.size() == mesh.vertices.size() && !mesh.vertices.empty();
  const std::string head = plyHeader(static_cast<int64_t>(mesh.vertices.size()),
                                     static_cast<int64_t>(mesh.triangles.size()), colored);
  std::vector<char> buf(head.begin(), head.end());
  buf.reserve(head.size() + mesh.vertices.size() * 15 + mesh.triangles.size() * 13);
  appendVertices(buf, mesh, colored);
  appendFaces(buf, mesh);
  writeFileAtomically(path, std::string_view(buf.data(), buf.size()));
}

PlyWriter::PlyWriter(std::string path, bool colored)
    : path_(std::move(path)), colored_(colored), vertex_out_(std::fopen(vertexPart(path_).c_str(), "w+b")),
      face_out_(std::fopen(facePart(path_).c_str(), "w+b")) {
  if (!vertex_out_ || !face_out_) {
    closeParts();
    cannotWrite(path_, "open");
  }
}

PlyWriter::~PlyWriter() { closeParts(); }

void PlyWriter::closeParts() {
  for (std::FILE** f : {&vertex_out_, &face_out_}) {
    if (*f) std::fclose(*f);
    *f = nullptr;
  }
  std::remove(vertexPart(path_).c_str());
  std::remove(facePart(path_).c_str());
}

void PlyWriter::add(const Mesh& piece) {
  if (!vertex_out_) throw Error("cannot write " + path_ + ": a mesh piece came after finish()");
  if (colored_ && piece.colors.size() != piece.vertices.size())
    throw Error("cannot write " + path_ + ": a mesh piece has " + std::to_string(piece.colors.size()) + " colors for " +
                std::to_string(piece.vertices.size()) + " vertices");
  std::vector<char> buf;
  buf.reserve(piece.vertices.size() * 15);
  auto flush = [&](std::FILE* f) {
    if (std::fwrite(buf.data(), 1, buf.size(), f) != buf.size()) cannotWrite(path_, "write");
    buf.clear();
  };
  appendVertices(buf, piece, colored_);
  flush(vertex_out_);
  appendFaces(buf, piece);
  flush(face_out_);
  vertices_ += static_cast<int64_t>(piece.vertices.size());
  faces_ += static_cast<int64_t>(piece.triangles.size());
}

void PlyWriter::finish() {
  if (!vertex_out_) throw Error("cannot write " + path_ + ": finish() called twice");
  const bool flushed = std::fflush(vertex_out_) == 0 && std::fflush(face_out_) == 0;
  if (!flushed) cannotWrite(path_, "write");
  const std::string tmp = path_ + ".tmp";  // as writeFileAtomically: renamed over PATH when whole
  std::FILE* out = std::fopen(tmp.c_str(), "wb");
  bool ok = out != nullptr && std::fputs(plyHeader(vertices_, faces_, colored_).c_str(), out) >= 0;
  std::vector<char> buf(1 << 20);
  for (std::FILE* part : {vertex_out_, face_out_}) {
    ok = ok && std::fseek(part, 0, SEEK_SET) == 0;
    for (size_t n; ok && (n = std::fread(buf.data(), 1, buf.size(), part)) > 0;) ok = std::fwrite(buf.data(), 1, n, out) == n;
    ok = ok && !std::ferror(part);
  }
  if (out && std::fclose(out) != 0) ok = false;
  closeParts();
  if (!ok || std::rename(tmp.c_str(), path_.c_str()) != 0) {
    std::remove(tmp.c_str());
    cannotWrite(path_, "write or rename");
  }
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
