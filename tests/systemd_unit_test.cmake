# The systemd unit as systemd reads it: `systemd-analyze verify` must have nothing to say
# about it (it exits 0 on unknown keys and bad values and only prints them, so any output
# fails this test), and every option its ExecStart passes must be one `run` accepts.
# ExecStart points at /usr/bin/virtual-encoder, which verify requires to exist: the test
# verifies a copy whose ExecStart points at the built binary instead, every other line as shipped.
find_program(SYSTEMD_ANALYZE systemd-analyze)
if(NOT SYSTEMD_ANALYZE)
  message(FATAL_ERROR "systemd-analyze not found (Debian package systemd; deploy/setup.sh installs it)")
endif()
file(READ "${UNIT}" unit)
string(FIND "${unit}" "ExecStart=/usr/bin/virtual-encoder " at)
if(at EQUAL -1)
  message(FATAL_ERROR "${UNIT}: no 'ExecStart=/usr/bin/virtual-encoder ...' line")
endif()
string(REPLACE "ExecStart=/usr/bin/virtual-encoder " "ExecStart=${BINARY} " copy "${unit}")
file(REMOVE_RECURSE "${OUT}")
file(MAKE_DIRECTORY "${OUT}")
get_filename_component(name "${UNIT}" NAME)
file(WRITE "${OUT}/${name}" "${copy}")
execute_process(COMMAND "${SYSTEMD_ANALYZE}" verify "${OUT}/${name}"
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0 OR NOT "${out}${err}" STREQUAL "")
  message(FATAL_ERROR "systemd-analyze verify ${name} (exit ${rc}):\n${out}${err}")
endif()

# The options ExecStart gives `run` exist.
string(REGEX MATCH "ExecStart=/usr/bin/virtual-encoder run([^\n]*)" line "${unit}")
if(NOT line)
  message(FATAL_ERROR "${UNIT}: ExecStart does not start 'virtual-encoder run'")
endif()
execute_process(COMMAND "${BINARY}" run --help RESULT_VARIABLE rc OUTPUT_VARIABLE help ERROR_VARIABLE help_err)
string(REGEX MATCHALL "--[a-z-]+" options "${CMAKE_MATCH_1}")
foreach(o ${options})
  string(FIND "${help}" "${o}" found)
  if(found EQUAL -1)
    message(FATAL_ERROR "ExecStart passes ${o}, which `virtual-encoder run --help` does not list:\n${help}")
  endif()
endforeach()
list(LENGTH options n)
message(STATUS "systemd-analyze verify: nothing to report; ExecStart's ${n} options are run's: OK")
