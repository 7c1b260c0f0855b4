# rekon_warnings: the warning set every rekon target compiles with.
add_library(rekon_warnings INTERFACE)
target_compile_options(rekon_warnings INTERFACE
  $<$<COMPILE_LANGUAGE:CXX>:-Wall -Wextra -Wpedantic -Wnon-virtual-dtor>
  $<$<AND:$<COMPILE_LANGUAGE:CXX>,$<CXX_COMPILER_ID:GNU>>:-Wshadow=local>)
if(REKON_WERROR)
  target_compile_options(rekon_warnings INTERFACE $<$<COMPILE_LANGUAGE:CXX>:-Werror>)
endif()
