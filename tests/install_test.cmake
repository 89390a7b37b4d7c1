# Installs the build into a scratch prefix (/usr layout) and checks the files.
file(REMOVE_RECURSE "${OUT}")
execute_process(COMMAND ${CMAKE_COMMAND} --install "${BUILD}" --prefix "${OUT}/usr" RESULT_VARIABLE rc OUTPUT_QUIET)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "cmake --install failed: ${rc}")
endif()
foreach(f
    usr/bin/virtual-encoder
    usr/lib/systemd/system/virtual-encoder.service
    usr/lib/sysctl.d/60-virtual-encoder.conf
    usr/share/virtual-encoder/dds-profiles.xml
    usr/share/virtual-encoder/install-machine.sh
    usr/share/virtual-encoder/config/machines/sim.yaml
    usr/share/virtual-encoder/config/motors/sim-12mm.yaml
    usr/share/doc/virtual-encoder/README.md
    usr/share/doc/virtual-encoder/docs/service.md
    usr/share/doc/virtual-encoder/docs/configuration.md)
  if(NOT EXISTS "${OUT}/${f}")
    message(FATAL_ERROR "missing after install: ${f}")
  endif()
endforeach()
execute_process(COMMAND "${OUT}/usr/bin/virtual-encoder" check RESULT_VARIABLE rc OUTPUT_VARIABLE out)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "the installed binary's check failed: ${out}")
endif()
message(STATUS "install tree complete; the installed binary checks the built-in machine: OK")
