# cmake -DWEB_DIR=... -DOUT=... -P embed_web.cmake: the page's files
# (web/) as string literals in OUT, so that rekon-viewer carries its page.
set(assets
  "/|index.html|text/html"
  "/index.html|index.html|text/html"
  "/app.js|app.js|text/javascript"
  "/style.css|style.css|text/css")
set(body "// Generated from services/viewer/web/ by embed_web.cmake; do not edit.\n")
string(APPEND body "#include \"rekon/viewer/web_assets.hpp\"\n\nnamespace rekon::viewer {\nnamespace {\n")
string(APPEND body "const WebAsset kAssets[] = {\n")
foreach(asset ${assets})
  string(REPLACE "|" ";" parts "${asset}")
  list(GET parts 0 route)
  list(GET parts 1 file)
  list(GET parts 2 type)
  file(READ ${WEB_DIR}/${file} content)
  string(FIND "${content}" ")rekonweb\"" clash)
  if(NOT clash EQUAL -1)
    message(FATAL_ERROR "${file} contains the raw-string delimiter )rekonweb\"")
  endif()
  string(APPEND body "  {\"${route}\", \"${type}; charset=utf-8\", R\"rekonweb(${content})rekonweb\"},\n")
endforeach()
string(APPEND body "};\n}  // namespace\n\nconst WebAsset* findWebAsset(std::string_view path) {\n")
string(APPEND body "  for (const WebAsset& a : kAssets) {\n    if (a.path == path) return &a;\n  }\n  return nullptr;\n}\n\n")
string(APPEND body "}  // namespace rekon::viewer\n")
file(WRITE ${OUT}.tmp "${body}")
file(COPY_FILE ${OUT}.tmp ${OUT} ONLY_IF_DIFFERENT)
file(REMOVE ${OUT}.tmp)
