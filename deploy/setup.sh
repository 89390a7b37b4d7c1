#!/usr/bin/env bash
# Installs the Debian 12 packages Virtual Encoder needs. Idempotent: does nothing when
# every package of the chosen set is present.
#   deploy/setup.sh          what building, running and testing need (the test command, tests/run.sh)
#   deploy/setup.sh --run    what building and running need, nothing for the tests (the demo, deploy/demo.sh)
#   deploy/setup.sh --list [--run]   print the chosen set, one package a line, and install nothing
set -euo pipefail

# Building and running the product (configured with -DVE_BUILD_TESTS=OFF).
RUN_PACKAGES=(
  build-essential cmake ninja-build pkg-config
  # Fast DDS; fastddsgen generates the DDS types at build time and is a Java program
  libfastrtps-dev libfastcdr-dev fastddsgen default-jre-headless
  libeigen3-dev libyaml-cpp-dev libcli11-dev libspdlog-dev libfmt-dev
  # systemd readiness and watchdog (sd_notify); .deb packaging (dpkg-shlibdeps; build-essential needs it anyway)
  libsystemd-dev dpkg-dev
)

# Only the tests, the fuzzers, the sanitizer runs and the benchmarks need these.
TEST_PACKAGES=(
  libgtest-dev libgmock-dev libbenchmark-dev
  # `fastdds shm clean` between test runs
  fastdds-tools
  # systemd-analyze for the unit's tests
  systemd
  # fuzzing (libFuzzer) needs clang and its runtime
  clang libclang-rt-14-dev
  # a second DDS implementation, for the interoperability test
  cyclonedds-dev cyclonedds-tools
  # a real kernel CAN stack in a small VM, for the SocketCAN tests (the build machines' kernels have no CAN)
  qemu-system-x86 busybox-static kmod can-utils iproute2
)

run_only=0
list=0
for arg in "$@"; do
  case "$arg" in
    --run) run_only=1 ;;
    --list) list=1 ;;
    -h|--help) sed -n '2,6s/^# \{0,1\}//p' "$0"; exit 0 ;;
    *) echo "setup: unknown argument '$arg' (usage: deploy/setup.sh [--run] [--list])" >&2; exit 2 ;;
  esac
done

PACKAGES=("${RUN_PACKAGES[@]}")
what="building and running"
if [ "$run_only" -eq 0 ]; then
  PACKAGES+=("${TEST_PACKAGES[@]}")
  what="building, running and testing"
fi

if [ "$list" -eq 1 ]; then
  printf '%s\n' "${PACKAGES[@]}"
  exit 0
fi

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#PACKAGES[@]} packages for $what present"
  exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
echo "setup: installing for $what: ${missing[*]}"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
