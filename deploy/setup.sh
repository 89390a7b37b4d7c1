#!/usr/bin/env bash
# Installs everything Virtual Encoder needs to build, test and run on Debian 12.
# Idempotent: does nothing when all packages are present.
set -euo pipefail

PACKAGES=(
  build-essential cmake ninja-build pkg-config
  libfastrtps-dev libfastcdr-dev fastddsgen fastdds-tools default-jre-headless
  libeigen3-dev libyaml-cpp-dev libcli11-dev libspdlog-dev libfmt-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  # systemd readiness and watchdog (sd_notify); .deb packaging; systemd-analyze for the unit's test
  libsystemd-dev dpkg-dev systemd
  # fuzzing (libFuzzer) needs clang and its runtime
  clang libclang-rt-14-dev
  # a second DDS implementation, for the interoperability test
  cyclonedds-dev cyclonedds-tools
  # a real kernel CAN stack in a small VM, for the SocketCAN tests (the build machines' kernels have no CAN)
  qemu-system-x86 busybox-static kmod can-utils iproute2
)

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#PACKAGES[@]} packages present"
  exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
echo "setup: installing ${missing[*]}"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
