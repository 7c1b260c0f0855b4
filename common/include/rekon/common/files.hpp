#pragma once
// Files that must never be seen half-written (a session's files): the bytes
// go to PATH.tmp, which is renamed over PATH, so a reader, or what a killed
// process left, has the old or the new content, never a mix. No fsync: this
// guards against processes that die (kill -9, a crash), not power cuts,
// which would cost the writer a disk flush per file.
#include <string>
#include <string_view>

namespace rekon {

// rekon::Error naming the file and the reason (e.g. no space left) when it cannot be written.
void writeFileAtomically(const std::string& path, std::string_view bytes);

}  // namespace rekon
