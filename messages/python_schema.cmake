# Writes OUT (rekon_schema.py) with the schema_version of BUS_HPP's kSchemaVersion.
file(STRINGS ${BUS_HPP} line REGEX "kSchemaVersion = [0-9]+;")
string(REGEX MATCH "kSchemaVersion = ([0-9]+)" _ "${line}")
if(NOT CMAKE_MATCH_1)
  message(FATAL_ERROR "${BUS_HPP}: no 'kSchemaVersion = N;' found; the Python types need the schema version")
endif()
file(WRITE ${OUT} "# Generated from ${BUS_HPP} at build time; do not edit.\nSCHEMA_VERSION = ${CMAKE_MATCH_1}\n")
