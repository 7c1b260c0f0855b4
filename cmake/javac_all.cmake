# cmake -DJAVAC=... -DLCM_JAR=... -DSRC=dir -DCLASSES=dir -P javac_all.cmake:
# compiles every .java under SRC (lcm-gen's output, whose file names are known
# only after it ran) into CLASSES.
file(GLOB_RECURSE sources ${SRC}/*.java)
if(NOT sources)
  message(FATAL_ERROR "no .java files under ${SRC}: lcm-gen -j wrote nothing")
endif()
execute_process(COMMAND ${JAVAC} -nowarn -encoding UTF-8 -cp ${LCM_JAR} -d ${CLASSES} ${sources}
                RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "javac failed on lcm-gen's Java types (output above)")
endif()
