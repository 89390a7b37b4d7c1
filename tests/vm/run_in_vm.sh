#!/bin/sh
# Boots the cached VM (prepare.sh) and runs SCRIPT inside it, as root, chrooted
# into the host's root (shared over 9p), with vcan0 (CAN FD capable, mtu 72)
# and vcan1 up. SCRIPT sees the same paths as the host; it should write what
# the host needs to read into files. Usage: run_in_vm.sh CACHE_DIR SCRIPT [TIMEOUT_S]
# Exit: 0 the VM ran the script and powered off; 77 qemu cannot run here;
# 1 the VM failed or timed out. The console goes to console.log beside SCRIPT (each
# run its own: two runs may boot a VM each from one cache at the same time).
set -eu
CACHE=$(cd "${1:?usage: run_in_vm.sh CACHE_DIR SCRIPT [TIMEOUT_S]}" && pwd)
SCRIPT=${2:?script}
LIMIT=${3:-150}
case "$SCRIPT" in /*) ;; *) SCRIPT="$(pwd)/$SCRIPT" ;; esac
CONSOLE="$(dirname "$SCRIPT")/console.log"
[ -f "$CACHE/ready" ] || { echo "run_in_vm: run prepare.sh first" >&2; exit 1; }
command -v qemu-system-x86_64 >/dev/null || { echo "SKIP: qemu-system-x86_64 not installed"; exit 77; }
MEM=${VE_VM_MEM:-1024}
# qemu ends with whoever started this script: it stays in the caller's process group
# (timeout --foreground makes none of its own), and timeout and qemu are each killed
# by the kernel when their parent dies (setpriv --pdeathsig).
PDS=""
if setpriv --pdeathsig KILL true 2>/dev/null; then PDS="setpriv --pdeathsig KILL"; fi
set +e
$PDS timeout --foreground -k 5 "$LIMIT" $PDS qemu-system-x86_64 -accel tcg -m "$MEM" -smp 2 -nographic -no-reboot \
  -kernel "$CACHE/vmlinuz" -initrd "$CACHE/initramfs.gz" \
  -append "console=ttyS0 quiet panic=-1 vecmd=$SCRIPT" \
  -virtfs local,path=/,mount_tag=hostroot,security_model=passthrough,id=hostroot,multidevs=remap \
  > "$CONSOLE" 2>&1 </dev/null
rc=$?
set -e
if [ $rc -eq 124 ] || [ $rc -eq 137 ]; then echo "run_in_vm: VM timed out after ${LIMIT}s; console in $CONSOLE" >&2; exit 1; fi
if [ $rc -ne 0 ]; then
  if grep -qiE "could not initialize|failed to initialize|not supported|permission denied" "$CONSOLE"; then
    echo "SKIP: qemu cannot run here (exit $rc):"; head -n 5 "$CONSOLE"; exit 77
  fi
  echo "run_in_vm: qemu exited with $rc; console in $CONSOLE" >&2; exit 1
fi
exit 0
