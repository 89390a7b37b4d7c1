# ---- commissioning walk: docs/commissioning.md's rehearsal, run as written ----
# tests/commissioning/walk.sh extracts the guide's `<!-- walk: NAME [can] -->` blocks and
# runs them in order (the `can` ones in the SocketCAN VM of tests/vm, whose kernel and
# initramfs are cached in ${CMAKE_BINARY_DIR}/vm, shared with SocketCanVm.GuestSuite),
# then checks each step's outcome. Label vm: left out of the sanitizer stages
# (tests/sanitizers/run.sh runs -LE 'vm|interop'); exit 77 (skipped, saying why) only
# where qemu or the kernel package is unavailable.
add_test(NAME commissioning.WalkFollowsTheGuide
  COMMAND /bin/sh ${PROJECT_SOURCE_DIR}/tests/commissioning/walk.sh ${PROJECT_SOURCE_DIR}
          $<TARGET_FILE:virtual-encoder> ${CMAKE_BINARY_DIR}/vm ${CMAKE_CURRENT_BINARY_DIR}/commissioning-walk)
set_tests_properties(commissioning.WalkFollowsTheGuide PROPERTIES
  LABELS "vm;integration" TIMEOUT 900 RUN_SERIAL TRUE SKIP_RETURN_CODE 77)
# ---- end commissioning walk ----
