#pragma once
// What `rekon --version` says: the git revision the binary was built from
// (with "+local changes" when the checkout had uncommitted ones) and the
// CMake build type; written at build time by version_info.cmake.
namespace rekon {
const char* gitRevision();
const char* buildType();
}  // namespace rekon
