#include "rekon/common/record_journal.hpp"

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <utility>

#include "rekon/common/error.hpp"

namespace rekon {
namespace {

constexpr char kMagic[8] = {'R', 'K', 'J', 'R', 'N', 'L', '0', '1'};
constexpr size_t kHeader = 2 * sizeof(uint32_t);
constexpr size_t kTrailer = sizeof(uint32_t);

uint32_t fnv1a32(const char* data, size_t n, uint32_t h = 2166136261u) {
  for (size_t i = 0; i < n; ++i) h = (h ^ static_cast<unsigned char>(data[i])) * 16777619u;
  return h;
}

template <class T>
T at(const std::string& bytes, size_t offset) {
  T v;
  std::memcpy(&v, bytes.data() + offset, sizeof(T));
  return v;
}

// A whole record's frame (header, payload, trailer) that starts at `offset`
// in the file, as `into`; false when its checksum does not match.
bool checkedRecord(const std::string& frame, uint64_t offset, JournalRecord& into) {
  const auto size = at<uint32_t>(frame, sizeof(uint32_t));
  if (at<uint32_t>(frame, kHeader + size) != fnv1a32(frame.data(), kHeader + size)) return false;
  into.tag = at<uint32_t>(frame, 0);
  into.bytes.assign(frame, kHeader, size);
  into.offset = offset;
  return true;
}

// n bytes from `fd` at `from` (pread: the descriptor's position is left alone).
bool readAll(int fd, char* into, size_t n, uint64_t from) {
  while (n > 0) {
    const ssize_t r = ::pread(fd, into, n, static_cast<off_t>(from));
    if (r < 0 && errno == EINTR) continue;
    if (r <= 0) return false;
    into += r;
    from += static_cast<uint64_t>(r);
    n -= static_cast<size_t>(r);
  }
  return true;
}

bool writeAll(int fd, const char* data, size_t n) {
  while (n > 0) {
    const ssize_t w = ::write(fd, data, n);
    if (w < 0 && errno == EINTR) continue;
    if (w <= 0) return false;
    data += w;
    n -= static_cast<size_t>(w);
  }
  return true;
}

}  // namespace

JournalScan scanRecordJournal(const std::string& path, const std::function<bool(JournalRecord&)>& visit) {
  JournalScan out;
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) return out;
  const auto file_size = static_cast<uint64_t>(in.tellg());
  in.seekg(0);
  if (file_size == 0) return out;  // created, killed before the magic went out
  char magic[sizeof(kMagic)] = {};
  if (!in.read(magic, sizeof(magic)) || std::memcmp(magic, kMagic, sizeof(kMagic)) != 0) {
    if (in.bad()) throw Error("cannot read the journal " + path + "; check its permissions");
    throw Error(path + " is not a rekon journal (wrong magic); remove it to start without what it held");
  }
  uint64_t offset = sizeof(kMagic);
  std::string frame;  // header, payload and trailer of one record, reused
  JournalRecord record;
  while (offset + kHeader <= file_size) {
    frame.resize(kHeader);
    if (!in.read(frame.data(), kHeader)) break;
    const uint32_t size = at<uint32_t>(frame, sizeof(uint32_t));
    if (file_size - offset - kHeader < static_cast<uint64_t>(size) + kTrailer) break;
    frame.resize(kHeader + size + kTrailer);
    if (!in.read(frame.data() + kHeader, size + kTrailer)) break;
    if (!checkedRecord(frame, offset, record) || !visit(record)) break;
    ++out.records;
    offset += kHeader + size + kTrailer;
  }
  if (in.bad()) throw Error("cannot read the journal " + path + "; check its permissions");
  out.valid_bytes = offset;
  if (offset < file_size) {
    out.torn = true;
    spdlog::warn("{}: the record at byte {} is torn, damaged or unreadable (a kill in mid-write?); it and the {} bytes "
                 "after it are cut off, {} records kept",
                 path, offset, file_size - offset, out.records);
  }
  return out;
}

JournalRead readRecordJournal(const std::string& path, const AcceptRecord& accept) {
  JournalRead out;
  const JournalScan scan = scanRecordJournal(path, [&](JournalRecord& record) {
    if (accept && !accept(record)) return false;
    out.records.push_back(std::move(record));
    return true;
  });
  out.valid_bytes = scan.valid_bytes;
  out.torn = scan.torn;
  return out;
}

RecordJournal::RecordJournal(const std::string& path, bool restarted, const AcceptRecord& accept) : path_(path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (const fs::path parent = fs::path(path).parent_path(); !parent.empty()) fs::create_directories(parent, ec);
  if (restarted) contents_ = readRecordJournal(path, accept);
  const bool keep = restarted && contents_.valid_bytes > 0;
  fd_ = ::open(path.c_str(), O_WRONLY | O_CREAT | O_CLOEXEC | (keep ? 0 : O_TRUNC), 0644);
  if (fd_ < 0) throw Error("cannot write the journal " + path + " (" + std::strerror(errno) + "); check that the folder is writable");
  // A restart appends after the last good record: a torn one is cut off.
  const bool ok = keep ? ::ftruncate(fd_, static_cast<off_t>(contents_.valid_bytes)) == 0 &&
                             ::lseek(fd_, 0, SEEK_END) == static_cast<off_t>(contents_.valid_bytes)
                       : writeAll(fd_, kMagic, sizeof(kMagic));
  if (!ok) {
    const std::string why = std::strerror(errno);
    ::close(fd_);
    fd_ = -1;
    throw Error("cannot write the journal " + path + " (" + why + "); check the disk and the folder's permissions");
  }
  end_ = keep ? contents_.valid_bytes : sizeof(kMagic);
  read_fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
}

RecordJournal::~RecordJournal() {
  if (fd_ >= 0) ::close(fd_);
  if (read_fd_ >= 0) ::close(read_fd_);
}

std::optional<JournalRecord> RecordJournal::readAt(uint64_t offset) const {
  std::string frame(kHeader, '\0');
  JournalRecord record;
  bool ok = read_fd_ >= 0 && readAll(read_fd_, frame.data(), kHeader, offset);
  if (ok) {
    const auto size = at<uint32_t>(frame, sizeof(uint32_t));
    frame.resize(kHeader + size + kTrailer);
    ok = readAll(read_fd_, frame.data() + kHeader, size + kTrailer, offset + kHeader) &&
         checkedRecord(frame, offset, record);
  }
  if (!ok) {
    spdlog::error("cannot read back the record at byte {} of the journal {} ({}); it is left out of what is sent "
                  "again: check the disk and that nothing else writes the file",
                  offset, path_, read_fd_ < 0 ? "not open for reading" : "short read or bad checksum");
    return std::nullopt;
  }
  return record;
}

std::optional<uint64_t> RecordJournal::append(uint32_t tag, const std::string& bytes) {
  if (fd_ < 0) return std::nullopt;
  const auto t0 = std::chrono::steady_clock::now();
  const auto size = static_cast<uint32_t>(bytes.size());
  buffer_.clear();
  buffer_.append(reinterpret_cast<const char*>(&tag), sizeof(tag));
  buffer_.append(reinterpret_cast<const char*>(&size), sizeof(size));
  buffer_.append(bytes);
  const uint32_t sum = fnv1a32(buffer_.data(), buffer_.size());
  buffer_.append(reinterpret_cast<const char*>(&sum), sizeof(sum));
  if (writeAll(fd_, buffer_.data(), buffer_.size())) {
    ++appended_.records;
    appended_.bytes += static_cast<int64_t>(buffer_.size());
    appended_.seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const uint64_t offset = end_;
    end_ += buffer_.size();
    return offset;
  }
  spdlog::error("cannot append to the journal {} ({}; disk full?): no more journal, a restart rebuilds only what "
                "came before",
                path_, std::strerror(errno));
  ::close(fd_);
  fd_ = -1;
  return std::nullopt;
}

}  // namespace rekon
