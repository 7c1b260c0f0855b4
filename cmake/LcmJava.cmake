# Java types of messages/*.lcm, generated at build time and never committed.
# Included from messages/CMakeLists.txt (REKON_LCM_SCHEMAS).
#   rekon_java_msgs: ${CMAKE_BINARY_DIR}/java/rekon_msgs.jar (lcm-gen -j, javac
#     against lcm.jar), so that lcm-spy (`rekon spy`) decodes rekon's channels.
#     Built only when a JDK and lcm.jar (Debian's liblcm-java, or the one in
#     the project's .venv from PyPI's lcm) are found.
find_package(Java COMPONENTS Development QUIET)
file(GLOB venv_java_dir ${CMAKE_SOURCE_DIR}/.venv/lib/python3*/site-packages/share/java)
find_file(REKON_LCM_JAR lcm.jar PATHS /usr/share/java ${venv_java_dir} NO_DEFAULT_PATH
          DOC "lcm.jar that rekon_msgs.jar is compiled against (Debian's liblcm-java or PyPI's lcm)")
if(NOT Java_JAVAC_EXECUTABLE OR NOT Java_JAR_EXECUTABLE)
  message(STATUS "rekon: lcm-spy types jar OFF (no JDK; apt-get install default-jdk-headless)")
elseif(NOT REKON_LCM_JAR)
  message(STATUS "rekon: lcm-spy types jar OFF (no lcm.jar; apt-get install liblcm-java)")
else()
  set(java_dir ${CMAKE_BINARY_DIR}/java)
  set(REKON_JAVA_MSGS_JAR ${java_dir}/rekon_msgs.jar)
  add_custom_command(
    OUTPUT ${REKON_JAVA_MSGS_JAR}
    COMMAND ${CMAKE_COMMAND} -E rm -rf ${java_dir}/src ${java_dir}/classes
    COMMAND ${CMAKE_COMMAND} -E make_directory ${java_dir}/src ${java_dir}/classes
    COMMAND ${LCM_GEN} --java --jpath ${java_dir}/src ${REKON_LCM_SCHEMAS}
    COMMAND ${CMAKE_COMMAND} -DJAVAC=${Java_JAVAC_EXECUTABLE} -DLCM_JAR=${REKON_LCM_JAR}
            -DSRC=${java_dir}/src -DCLASSES=${java_dir}/classes -P ${CMAKE_SOURCE_DIR}/cmake/javac_all.cmake
    COMMAND ${Java_JAR_EXECUTABLE} cf ${REKON_JAVA_MSGS_JAR} -C ${java_dir}/classes .
    DEPENDS ${REKON_LCM_SCHEMAS} ${CMAKE_SOURCE_DIR}/cmake/javac_all.cmake
    COMMENT "lcm-gen -j, javac: rekon_msgs.jar for lcm-spy")
  add_custom_target(rekon_java_msgs ALL DEPENDS ${REKON_JAVA_MSGS_JAR})
  message(STATUS "rekon: lcm-spy types jar ON (${REKON_JAVA_MSGS_JAR}, against ${REKON_LCM_JAR})")
endif()
