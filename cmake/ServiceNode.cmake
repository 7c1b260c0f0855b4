# rekon_add_service_node(NAME [LIBS lib...]): the node/ folder of
# services/NAME, the same shape for every service: its bus wiring (node/*.cpp
# but main.cpp) as the library rekon_NAME_node on top of the service's library
# rekon_NAME (tests run it in-process over a memory:// bus), and the thin
# node/main.cpp as build/bin/rekon-NAME. LIBS: what the wiring links besides.
function(rekon_add_service_node name)
  cmake_parse_arguments(NODE "" "" "LIBS" ${ARGN})
  file(GLOB sources CONFIGURE_DEPENDS ${CMAKE_CURRENT_SOURCE_DIR}/node/*.cpp)
  list(REMOVE_ITEM sources ${CMAKE_CURRENT_SOURCE_DIR}/node/main.cpp)
  add_library(rekon_${name}_node STATIC ${sources})
  target_include_directories(rekon_${name}_node PUBLIC ${CMAKE_CURRENT_SOURCE_DIR}/node)
  target_link_libraries(rekon_${name}_node PUBLIC rekon_${name} rekon_common
    PRIVATE rekon_warnings spdlog::spdlog ${NODE_LIBS})

  add_executable(rekon-${name} node/main.cpp)
  target_link_libraries(rekon-${name} PRIVATE rekon_${name}_node rekon_common rekon_warnings)
  set_target_properties(rekon-${name} PROPERTIES RUNTIME_OUTPUT_DIRECTORY ${CMAKE_BINARY_DIR}/bin)
endfunction()
