# lcm-gen's C++ decoders compute `sizeof(T) * length` in int: a hostile length
# (e.g. 0x7fffffff) overflows, passes the bounds check and reads far beyond the
# buffer. Every array element takes at least one byte, so a length above the
# bytes left is malformed: this inserts that check before every resize().
file(GLOB headers ${GEN_DIR}/rekon_msgs/*.hpp)
foreach(h ${headers})
  file(READ ${h} text)
  string(REGEX REPLACE
    "([ \t]*)this->([A-Za-z0-9_]+)\\.resize\\(this->([A-Za-z0-9_]+)\\);"
    "\\1if (this->\\3 < 0 || this->\\3 > maxlen - pos) return -1;\n\\1this->\\2.resize(this->\\3);"
    text "${text}")
  # Strings: a length below 1 (the terminating NUL is counted) passed
  # `len > maxlen - pos` and made assign(..., len - 1) read far out of bounds.
  string(REGEX REPLACE
    "if\\(__([A-Za-z0-9_]+)_len__ > maxlen - pos\\) return -1;"
    "if(__\\1_len__ < 1 || __\\1_len__ > maxlen - pos) return -1;"
    text "${text}")
  file(WRITE ${h} "${text}")
endforeach()
