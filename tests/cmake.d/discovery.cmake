# Plant scale: the Discovery Server deployment (deploy/discovery/) tested on a plant of
# network namespaces, and the scale benchmark (docs/scale.md).

# ---- Discovery Server on a plant of network namespaces ----
# tests/plant/discovery_server_test.sh: two servers, five encoders (2 axes at 1 kHz each)
# and a monitor, each in its own network namespace on one bridge; simple discovery
# against Discovery Server, servers killed and restarted, discovery datagrams counted
# (ve_plant_traffic), a real-time probe of the host's stalls (ve_pace_floor). Needs root (network namespaces); skips with 77 where they cannot be
# made. Label "plant": left out of the sanitizer stages (tests/sanitizers/run.sh), where
# ten 1 kHz axes cannot keep their rate and the figures would mean nothing.
add_executable(ve_plant_traffic plant/traffic_counter.cpp)
# The pacing floor: the scale benchmark's floor, and the test's probe of the host's stalls.
add_executable(ve_pace_floor plant/pace_floor.cpp)
target_link_libraries(ve_pace_floor PRIVATE ve_drivers)
add_test(NAME plant.DiscoveryServerOnNamespaces
  COMMAND ${CMAKE_CURRENT_SOURCE_DIR}/plant/discovery_server_test.sh
          $<TARGET_FILE:virtual-encoder> $<TARGET_FILE:ve_plant_traffic> ${PROJECT_SOURCE_DIR}
          $<TARGET_FILE:ve_pace_floor>)
set_tests_properties(plant.DiscoveryServerOnNamespaces PROPERTIES
  LABELS "integration;plant" RUN_SERIAL TRUE TIMEOUT 300 SKIP_RETURN_CODE 77)
# ---- end Discovery Server ----

# ---- scale benchmark (docs/scale.md) ----
# bench_scale runs `virtual-encoder run` with 1-16 axes at 4 kHz beside the pacing floor
# (ve_pace_floor) and a bare Fast DDS writer of the same writes (ve_bare_writer), with and
# without a subscriber (ve_bare_reader), and writes tests/bench/results/scale.md.
# A benchmark, not a test: run it by hand on a quiet host.
add_executable(ve_bare_writer plant/bare_writer.cpp)
target_link_libraries(ve_bare_writer PRIVATE ve_idl ve_drivers)
if(VE_BUILD_BENCHMARKS)
  add_executable(bench_scale plant/scale_bench.cpp)
  target_link_libraries(bench_scale PRIVATE yaml-cpp)
  target_compile_definitions(bench_scale PRIVATE
    VE_BENCH_SOURCE_DIR="${PROJECT_SOURCE_DIR}"
    VE_BINARY="$<TARGET_FILE:virtual-encoder>"
    VE_BARE_READER="$<TARGET_FILE:ve_bare_reader>"
    VE_BARE_WRITER="$<TARGET_FILE:ve_bare_writer>"
    VE_PACE_FLOOR="$<TARGET_FILE:ve_pace_floor>")
  add_dependencies(bench_scale virtual-encoder ve_bare_reader ve_bare_writer ve_pace_floor)
endif()
# ---- end scale benchmark ----

# The Discovery Server's unit verifies (systemd-analyze verify, as
# systemd.UnitVerifiesAndItsCommandLineIsAccepted does for the product's unit).
add_test(NAME systemd.DiscoveryServerUnitVerifies
  COMMAND ${CMAKE_CURRENT_SOURCE_DIR}/plant/verify_discovery_unit.sh ${PROJECT_SOURCE_DIR})
set_tests_properties(systemd.DiscoveryServerUnitVerifies PROPERTIES LABELS unit SKIP_RETURN_CODE 77)
