# The service recipe (docs/service.md), followed into a scratch root OUT instead of /:
#   cmake --install build --prefix OUT/usr
#   deploy/install-machine.sh --root OUT OUT/usr/share/virtual-encoder/config/machines/sim.yaml
# The machine file the unit runs (OUT/etc/virtual-encoder/machine.yaml) must then pass
# `virtual-encoder check` with the installed binary: its motor file, which sim.yaml names
# relative to itself, is found from /etc. A plain copy must not (the mistake this guards
# against). Every other shipped machine installs with its references resolved too. Last,
# `systemd-analyze verify` has nothing to say about the installed unit, pointed at the
# scratch root's binary and machine file (skipped, with a message, without systemd-analyze).
# Inputs: BUILD (the build tree), SOURCE (the source tree), OUT (scratch directory).
file(REMOVE_RECURSE "${OUT}")
execute_process(COMMAND ${CMAKE_COMMAND} --install "${BUILD}" --prefix "${OUT}/usr"
                RESULT_VARIABLE rc OUTPUT_QUIET)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "cmake --install failed: ${rc}")
endif()
set(bin "${OUT}/usr/bin/virtual-encoder")
set(share "${OUT}/usr/share/virtual-encoder/config")
set(machine "${OUT}/etc/virtual-encoder/machine.yaml")

function(install_machine src)
  execute_process(COMMAND bash "${SOURCE}/deploy/install-machine.sh" --root "${OUT}" ${ARGN} "${src}"
                  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  set(install_rc "${rc}" PARENT_SCOPE)
  set(install_out "${out}${err}" PARENT_SCOPE)
endfunction()

# 1. The recipe, as written.
install_machine("${share}/machines/sim.yaml")
if(NOT install_rc EQUAL 0)
  message(FATAL_ERROR "install-machine.sh sim.yaml (exit ${install_rc}):\n${install_out}")
endif()
execute_process(COMMAND "${bin}" check --config "${machine}" RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "virtual-encoder check --config ${machine} (exit ${rc}):\n${out}${err}")
endif()
file(READ "${machine}" text)
string(FIND "${text}" "motor: ${share}/motors/sim-12mm.yaml" at)
if(at EQUAL -1)
  message(FATAL_ERROR "${machine} does not name the installed motor file:\n${text}")
endif()
message(STATUS "recipe: ${machine} checks with the installed binary")

# 2. A second install keeps the (possibly edited) file unless told to replace it.
install_machine("${share}/machines/sim.yaml")
if(NOT install_rc EQUAL 2)
  message(FATAL_ERROR "install-machine.sh replaced an existing machine.yaml without --force (exit ${install_rc}):\n${install_out}")
endif()

# 3. The plain copy the recipe used to make does not check: its motor path no longer resolves.
file(COPY_FILE "${share}/machines/sim.yaml" "${OUT}/etc/virtual-encoder/plain-copy.yaml")
execute_process(COMMAND "${bin}" check --config "${OUT}/etc/virtual-encoder/plain-copy.yaml"
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(rc EQUAL 0 OR NOT "${out}${err}" MATCHES "cannot read motor file")
  message(FATAL_ERROR "a plain copy of sim.yaml to /etc was expected to fail on its motor path (exit ${rc}):\n${out}${err}")
endif()
file(REMOVE "${OUT}/etc/virtual-encoder/plain-copy.yaml")

# 4. Every shipped machine: its motor, calibration and CAN layout are found from /etc. The
#    simulator machines check clean; the CAN machines may fail only on the host's CAN support.
file(GLOB machines "${share}/machines/*.yaml")
foreach(m ${machines})
  get_filename_component(name "${m}" NAME)
  install_machine("${m}" --force)
  if("${install_out}" MATCHES "cannot read")
    message(FATAL_ERROR "${name}: a referenced file is not found from ${machine}:\n${install_out}")
  endif()
  if(name MATCHES "^sim" AND NOT install_rc EQUAL 0)
    message(FATAL_ERROR "${name}: installed as ${machine}, check failed (exit ${install_rc}):\n${install_out}")
  endif()
  if(NOT install_rc EQUAL 0 AND NOT install_rc EQUAL 1)
    message(FATAL_ERROR "${name}: install-machine.sh exit ${install_rc}:\n${install_out}")
  endif()
  message(STATUS "${name}: references resolved from /etc (install-machine.sh exit ${install_rc})")
endforeach()
install_machine("${share}/machines/sim.yaml" --force)

# 5. The installed unit, as systemd reads it, with the scratch root's binary and machine file.
find_program(SYSTEMD_ANALYZE systemd-analyze)
if(NOT SYSTEMD_ANALYZE)
  message(STATUS "SKIPPED: systemd-analyze not found (Debian package systemd): the unit was not verified")
  return()
endif()
file(READ "${OUT}/usr/lib/systemd/system/virtual-encoder.service" unit)
string(FIND "${unit}" "ExecStart=/usr/bin/virtual-encoder run --config /etc/virtual-encoder/machine.yaml" at)
if(at EQUAL -1)
  message(FATAL_ERROR "the installed unit does not run /etc/virtual-encoder/machine.yaml:\n${unit}")
endif()
string(REPLACE "ExecStart=/usr/bin/virtual-encoder " "ExecStart=${bin} " unit "${unit}")
string(REPLACE "--config /etc/virtual-encoder/machine.yaml" "--config ${machine}" unit "${unit}")
file(MAKE_DIRECTORY "${OUT}/verify")
file(WRITE "${OUT}/verify/virtual-encoder.service" "${unit}")
execute_process(COMMAND "${SYSTEMD_ANALYZE}" verify "${OUT}/verify/virtual-encoder.service"
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0 OR NOT "${out}${err}" STREQUAL "")
  message(FATAL_ERROR "systemd-analyze verify on the installed unit (exit ${rc}):\n${out}${err}")
endif()
message(STATUS "systemd-analyze verify: the installed unit has nothing to report")
