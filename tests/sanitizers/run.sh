#!/usr/bin/env bash
# Builds the product and its tests with a sanitizer and runs the test suite under it.
#   tests/sanitizers/run.sh asan   build-asan, -DVE_SANITIZE=address,undefined (ASan + LSan + UBSan)
#   tests/sanitizers/run.sh tsan   build-tsan, -DVE_SANITIZE=thread
#
# What runs:
#  - asan: every unit test, every integration test (real virtual-encoder processes talking
#    over a real Fast DDS stack, the command line, the systemd notify/watchdog test) and the
#    install-tree test;
#  - tsan: the integration tests but those named below. The unit tests exercise
#    single-threaded code only (the estimation core, the loaders, the simulator, the CAN
#    layout), where ThreadSanitizer has nothing to find, and run 50 times slower under it
#    (minutes per test).
# The child processes the integration tests start are the sanitized binary too.
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
#  - Realtime.WithoutPermissionWarnsOncePerSettingAndPublishes: it checks the warning for
#    a refused mlockall(), and the sanitizer runtimes replace mlockall() by a no-op that
#    succeeds (shadow memory cannot be locked), so the refusal never happens there.
# Left out of the TSan tree only (they run in the ASan/UBSan tree and in the plain one):
#  the tests whose verdict is a real-time figure of the 4 kHz stream. Under ThreadSanitizer
#  the product and the test process run 5 to 15 times slower, so on a 2-core machine with
#  any other work on it (a load of 3 to 8) the subscribers fall behind the stream and these
#  figures fail with no bug behind them; on an idle one they mostly pass (seen: 1.9-3.2 kHz
#  instead of 4 kHz +- 10 %, pauses of 0.4-1.2 s instead of < 50 ms, thousands of sequence
#  gaps, a 300 ms stall that raises no 20 ms deadline because the subscriber is still
#  working through its backlog):
#  - CalibrationDds.StartRunsInTheBackgroundWhileTheStateStreamKeepsPublishing (rate,
#    longest pause and gaps of the stream while a calibration runs);
#  - CalibrationDds.AbortStopsItPromptlyAndWritesNothing (the abort within 1 s);
#  - DdsInterface.DiagnosticsRoundTripBetweenTwoProcesses (the 4 kHz and 10 Hz rates);
#  - DdsInterface.ThreeAxesAreThreeInstancesWithIndependentDeadlines (misses of the
#    stalled axis against the others', 2000 samples within 5 s);
#  - DdsRoundTrip.TwoProcessesSequenceValuesDescriptionDeadlineAndShutdown (the miss
#    during a 300 ms stall, fewer than 1 % lost);
#  - DdsSecurity.OnlyThePermittedMonitorReadsTheState (4000 samples within 5 s). It also
#    ends, in most runs, with a race between two of Fast DDS's own threads in its
#    cryptography plugin (a crypto handle freed, from libfastrtps+0x6a1369, while
#    another thread compares one of its strings), in functions that Debian's stripped
#    libfastrtps does not name, so no suppression can name them;
#  and CalibrationKill.KilledAtAnyMomentLeavesTheOldOrTheNewFileNeverABrokenOne: 14 runs
#  of the single-threaded `calibrate` command, nothing for TSan to find, and past the
#  test's 120 s limit under it.
#  What these tests drive concurrently still runs under TSan in the others: a calibration
#  started over DDS beside the axis thread, then aborted, with the security plugins
#  (DdsSecurity.OnlyThePermittedMonitorStartsACalibration); two axis threads
#  (Realtime.RunPinsEachSampleThreadToItsCpus); `run` with DDS subscribers in the test
#  process and in `monitor` (DdsRoundTrip.PublishedPositionAtOneMetrePerSecondIsWithinSpec,
#  DdsInterface.LateJoiningSubscriberReceivesTheAxisDescription, Restart, Service, ...).
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

cmake -S . -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DVE_SANITIZE="$sanitize" \
  -DVE_BUILD_BENCHMARKS=OFF >/dev/null
targets=(ve_integration_tests virtual-encoder)
if [ "$kind" = asan ]; then targets+=(ve_unit_tests); fi
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
export TSAN_OPTIONS="$common:log_path=$logs/tsan:second_deadlock_stack=1:suppressions=$supp/tsan.supp:print_suppressions=0"

fastdds shm clean >/dev/null 2>&1 || true
status=0
# -L/-LE: the tests named above, without the VM and interop ones. The VM test binary is
# not built here, so its placeholder test (no labels) is left out too.
labels='unit|integration'
exclude='Realtime\.WithoutPermissionWarnsOncePerSettingAndPublishes'
if [ "$kind" = tsan ]; then
  labels='integration'
  exclude="$exclude|CalibrationDds\.StartRunsInTheBackgroundWhileTheStateStreamKeepsPublishing"
  exclude="$exclude|CalibrationDds\.AbortStopsItPromptlyAndWritesNothing"
  exclude="$exclude|DdsInterface\.DiagnosticsRoundTripBetweenTwoProcesses"
  exclude="$exclude|DdsInterface\.ThreeAxesAreThreeInstancesWithIndependentDeadlines"
  exclude="$exclude|DdsRoundTrip\.TwoProcessesSequenceValuesDescriptionDeadlineAndShutdown"
  exclude="$exclude|DdsSecurity\.OnlyThePermittedMonitorReadsTheState"
  exclude="$exclude|CalibrationKill\.KilledAtAnyMomentLeavesTheOldOrTheNewFileNeverABrokenOne"
fi
ctest --test-dir "$build" --output-on-failure --timeout 600 -L "$labels" -LE 'vm|interop' \
  -E "^($exclude)\$" "$@" || status=1
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
