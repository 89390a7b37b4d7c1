# CiA 406 (CANopen linear encoder) node: component/canopen, docs/canopen.md.
# The protocol's unit tests (tests/unit/canopen_*_test.cpp) are in ve_unit_tests and
# need the node's library; the node on a real kernel CAN stack is tested in the
# SocketCAN VM by ve_canopen_vm_tests (CanopenVm.GuestSuite boots the VM and runs the
# CanopenGuest.* tests of the same binary inside it, against a test master of its own).
target_link_libraries(ve_unit_tests PRIVATE ve_canopen)

ve_vm_test(ve_canopen_vm_tests vm/canopen_vm_test.cpp "CanopenVm.*" 400)

# The node's share of the SYNC-to-TPDO delay (a benchmark, not a test).
if(TARGET bench_canopen)
  target_link_libraries(bench_canopen PRIVATE ve_canopen)
endif()
