#pragma once
// The page's own files (services/viewer/web/), compiled into the binary at
// build time so that the viewer serves them with nothing installed beside it.
#include <string_view>

namespace rekon::viewer {

struct WebAsset {
  std::string_view path;          // as requested: "/", "/app.js", ...
  std::string_view content_type;
  std::string_view body;
};

// The asset served at `path`; nullptr when there is none.
const WebAsset* findWebAsset(std::string_view path);

}  // namespace rekon::viewer
