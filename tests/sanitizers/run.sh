#!/usr/bin/env bash
# Builds the product and its tests with a sanitizer and runs the test suite under it.
#   tests/sanitizers/run.sh asan   build-asan, -DVE_SANITIZE=address,undefined (ASan + LSan + UBSan)
#   tests/sanitizers/run.sh tsan   build-tsan, -DVE_SANITIZE=thread
#
# What runs, in both trees: every unit test, every integration test (real
# virtual-encoder processes talking over a real Fast DDS stack, the command line, the
# systemd notify/watchdog test) and the install-tree test. The child processes the
# integration tests start are the sanitized binary too.
# Under ThreadSanitizer the product and the tests run 5 to 15 times slower, under
# AddressSanitizer about 2 times: the integration tests that check real-time figures of
# the 4 kHz stream (rates, losses, pauses, promptness) still run every step and check
# every behaviour there, waiting longer, and judge those figures only at real speed, in
# the plain build (tests/integration/speed.hpp).
# Each test takes its DDS domains from the host-wide pool (docs/testing.md), so this can
# run while the plain suite, the other sanitizer or another checkout's suite runs.
# In the TSan tree every executable also carries tests/sanitizers/tsan_clock_interpose.cpp
# (CMakeLists.txt): libtsan does not intercept pthread_mutex_clocklock, with which Fast DDS
# takes its timed mutexes, and would report bogus races inside Fast DDS without it.
# Left out, in both trees:
#  - the SocketCAN VM test (label vm): it boots a kernel under qemu without KVM and runs
#    the test binary inside the guest's initramfs; the CAN layout and decoder it relies on
#    run under both sanitizers in the unit tests and under ASan/UBSan in the fuzzers;
#  - the Cyclone DDS interop test (label interop): it checks the wire format against a
#    second DDS implementation; our side of it is `virtual-encoder run`, which the DDS
#    integration tests already run under the sanitizer;
#  - the benchmarks (timing figures mean nothing under a sanitizer);
#  - the plant test (label plant, tests/cmake.d/discovery.cmake): ten 1 kHz axes, servers and
#    a monitor in network namespaces, judged on the stream's real-time figures;
#  - Realtime.WithoutPermissionWarnsOncePerSettingAndPublishes: it checks the warning for
#    a refused mlockall(), and the sanitizer runtimes replace mlockall() by a no-op that
#    succeeds (shadow memory cannot be locked), so the refusal never happens there.
# Left out of the TSan tree only (they run in the plain and ASan/UBSan trees):
#  - PublisherKill.*: its subscribers include the Cyclone DDS reader and Fast DDS's
#    type-object registry, uninstrumented libraries whose races TSan reports in them;
#  - DdsTypeObject.AnnouncedOnRequest: it has `run` announce TypeObjects, on purpose, so
#    its watcher builds them in that same registry (the race it documents: the product
#    does not announce them by default, DdsOptions::type_object);
#  - the bad-input corpora's file and command-line validation: BadInputFiles.*
#    (tests/integration/bad_input_files_test.cpp) and, of bad_input_cli_test.cpp,
#    BadInputCli.*, BadInput/CommandLine.*, BadInput/CommandLineValue.* and
#    BadInput/Help.*. Each case is a short-lived process that reads a file or its
#    arguments on one thread and refuses them before any other thread starts, so there
#    is no interleaving for TSan to judge, while its slowdown made them the longest part
#    of the stage (BadInputFiles.CalibrationFiles alone 67 s). ASan/UBSan is the
#    sanitizer that judges that parsing, and the fuzzers cover the same parsers.
#    BadInput/Signal.* and BadInput/DiskError.* stay: they signal or starve running
#    subcommands (run, monitor, record, calibrate), whose threads TSan does judge;
#  - the calibrations and the population's accuracy guards, SelfCalibration.*,
#    SelfCalibrationPopulation.*, Seeds/Population*, Population*HeldOut.* and RealisticCalibration.*: pure
#    computation of the core and the simulator on the test's one thread (no thread is
#    started), which TSan slowed to 10-205 s each (about 1,100 s of the stage's CPU) with
#    nothing to judge. ASan/UBSan runs them.
# Every sanitizer report fails the stage, including one from a child process that a test
# stopped or whose exit code it does not look at: reports go to $BUILD/sanitizer-logs/
# and any file there fails the run.
set -euo pipefail
cd "$(dirname "$0")/../.."
kind="${1:?usage: tests/sanitizers/run.sh asan|tsan [ctest args...]}"
shift
case "$kind" in
  asan) sanitize=address,undefined; build=build-asan ;;
  tsan) sanitize=thread; build=build-tsan ;;
  *) echo "sanitizers: unknown kind '$kind' (asan or tsan)" >&2; exit 2 ;;
esac
supp="$PWD/tests/sanitizers"
logs="$PWD/$build/sanitizer-logs"

# -g1: line tables and function names, all a sanitizer's report needs; full -g made
# the two sanitizer builds about a quarter slower to compile and link.
cmake -S . -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DVE_SANITIZE="$sanitize" \
  -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG" -DCMAKE_C_FLAGS_RELWITHDEBINFO="-O2 -g1 -DNDEBUG" \
  -DVE_BUILD_BENCHMARKS=OFF >/dev/null
targets=(ve_integration_tests virtual-encoder ve_unit_tests)
cmake --build "$build" --parallel "$(nproc)" --target "${targets[@]}"

rm -rf "$logs"
mkdir -p "$logs"
common="halt_on_error=1:abort_on_error=1:disable_coredump=1:print_stacktrace=1"
export ASAN_OPTIONS="$common:log_path=$logs/asan:detect_leaks=1:detect_stack_use_after_return=1:strict_init_order=1:check_initialization_order=1"
# new_delete_type_mismatch=0: Debian's libfastrtps 2.9 deletes RTPSReader through a
# pointer of a smaller type inside its own destructors (RTPSReader::~RTPSReader, called
# when a DataReader is deleted); ASan has no suppression for this check, so it is off.
export ASAN_OPTIONS="$ASAN_OPTIONS:new_delete_type_mismatch=0"
export LSAN_OPTIONS="suppressions=$supp/lsan.supp:print_suppressions=0"
export UBSAN_OPTIONS="$common:log_path=$logs/ubsan"
tsan_options() { echo "$common:log_path=$logs/tsan:second_deadlock_stack=1:suppressions=$1:print_suppressions=0"; }
export TSAN_OPTIONS="$(tsan_options "$supp/tsan.supp")"

fastdds shm clean >/dev/null 2>&1 || true
status=0
# -L/-LE: the tests named above, without the VM, interop and plant ones. The VM test binary is
# not built here, so its placeholder test (no labels) is left out too.
labels='unit|integration'
exclude='Realtime\.WithoutPermissionWarnsOncePerSettingAndPublishes'
# --parallel: the unit tests run side by side; the integration tests are RUN_SERIAL.
# Under TSan the DDS Security tests run in a ctest of their own, with the suppressions of
# tsan-security.supp added (Fast DDS's cryptography plugin races in functions TSan cannot
# name; that file says why it names libraries, and why only there).
security='DdsSecurity\..*'
# TSan only: the publisher kill test and the bad-input corpora (see the header for why).
if [ "$kind" = tsan ]; then
  exclude="$exclude|$security|PublisherKill\..*|DdsTypeObject\.AnnouncedOnRequest|BadInputFiles\..*|BadInputCli\..*"
  exclude="$exclude|BadInput/CommandLine\..*|BadInput/CommandLineValue\..*|BadInput/Help\..*"
  exclude="$exclude|SelfCalibration\..*|SelfCalibrationPopulation\..*|Seeds/Population.*|Population.*HeldOut\..*|RealisticCalibration\..*"
fi
ctest --test-dir "$build" --output-on-failure --timeout 600 --parallel "$(nproc)" -L "$labels" -LE 'vm|interop|plant' \
  -E "^($exclude)\$" "$@" || status=1
if [ "$kind" = tsan ]; then
  cat "$supp/tsan.supp" "$supp/tsan-security.supp" >"$build/tsan-security.supp"
  TSAN_OPTIONS="$(tsan_options "$PWD/$build/tsan-security.supp")" \
    ctest --test-dir "$build" --output-on-failure --timeout 600 -L integration -R "^($security)\$" "$@" || status=1
fi
fastdds shm clean >/dev/null 2>&1 || true

reports=$(find "$logs" -type f | sort)
if [ -n "$reports" ]; then
  echo "sanitizers ($kind): $(echo "$reports" | wc -l) report file(s):"
  for f in $reports; do
    echo "---- $f"
    head -n 80 "$f"
  done
  status=1
fi
if [ $status -eq 0 ]; then echo "sanitizers ($kind): test suite passed, no reports"; fi
exit $status
