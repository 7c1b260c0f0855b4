#pragma once
#include "rekon/common/error.hpp"

namespace rekon::store {

// A store whose writer died inside the segment's allocator: its free lists
// may be half-changed, so nothing in it can be trusted any more. The first
// process to lock it after the death hears it, and so does every later one.
class BrokenStore : public Error {
 public:
  using Error::Error;
};

}  // namespace rekon::store
