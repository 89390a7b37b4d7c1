# The layers of the source tree point one way: component/core includes only core;
# drivers/ includes core and drivers, never config or app; component/config includes
# core, drivers and config, never app; component/canopen (the CANopen protocol) includes
# core and itself only; component/app may include all of them.
# Fails naming every include that points the wrong way (file:line: the include).
# Usage: cmake -DSOURCE=<repository root> -P layers_test.cmake
set(rules
  "component/core|core"
  "drivers|core,sim,socketcan,replay"
  "component/config|core,config,sim,socketcan,replay"
  "component/canopen|core,canopen")
set(problems "")
set(checked 0)
foreach(rule ${rules})
  string(REPLACE "|" ";" parts "${rule}")
  list(GET parts 0 dir)
  list(GET parts 1 allowed)
  string(REPLACE "," ";" allowed "${allowed}")
  file(GLOB_RECURSE files "${SOURCE}/${dir}/*.hpp" "${SOURCE}/${dir}/*.cpp")
  foreach(f ${files})
    math(EXPR checked "${checked} + 1")
    file(STRINGS "${f}" lines)
    set(n 0)
    foreach(line IN LISTS lines)
      math(EXPR n "${n} + 1")
      # Quoted includes with a directory: "layer/file.hpp". Local ones ("file.hpp") stay in the layer.
      if(line MATCHES "^[ \t]*#[ \t]*include[ \t]+\"([A-Za-z0-9_]+)/[^\"]+\"")
        set(target "${CMAKE_MATCH_1}")
        list(FIND allowed "${target}" at)
        if(at EQUAL -1)
          file(RELATIVE_PATH rel "${SOURCE}" "${f}")
          string(APPEND problems "${rel}:${n}: ${line} (${dir} may include only: ${allowed})\n")
        endif()
      endif()
    endforeach()
  endforeach()
endforeach()
if(checked LESS 20)
  message(FATAL_ERROR "only ${checked} files found under ${SOURCE}: wrong SOURCE?")
endif()
if(NOT problems STREQUAL "")
  message(FATAL_ERROR "includes that point up a layer:\n${problems}")
endif()
message(STATUS "${checked} files: every include points down a layer or stays in its own")
