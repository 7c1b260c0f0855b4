# rekon_warnings: the warning set every rekon target compiles with.
add_library(rekon_warnings INTERFACE)
target_compile_options(rekon_warnings INTERFACE
  $<$<COMPILE_LANGUAGE:CXX>:-Wall -Wextra -Wpedantic -Wnon-virtual-dtor>
  $<$<AND:$<COMPILE_LANGUAGE:CXX>,$<CXX_COMPILER_ID:GNU>>:-Wshadow=local>)
if(REKON_WERROR)
  target_compile_options(rekon_warnings INTERFACE $<$<COMPILE_LANGUAGE:CXX>:-Werror>)
endif()
if(REKON_SANITIZE)
  add_compile_options(-fsanitize=address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer)
  add_link_options(-fsanitize=address,undefined)
endif()
if(REKON_FUZZ)
  # Coverage instrumentation for libFuzzer in every library the fuzzers link.
  add_compile_options(-fsanitize=fuzzer-no-link)
endif()
