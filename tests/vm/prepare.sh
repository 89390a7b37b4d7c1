#!/bin/sh
# Prepares (once) what the SocketCAN VM tests boot: a Debian kernel with its
# modules and a busybox initramfs that loads the 9p + CAN modules, mounts the
# host's root over 9p and runs a command there with vcan0 up.
# Recipe: ../shared/docs/socketcan-in-a-vm.md.   Usage: prepare.sh CACHE_DIR
# Prints nothing on success when the cache is already complete.
# Exit codes: 0 ready; 77 a tool or the kernel package is unavailable (the
# caller skips, saying why); 1 anything else.
set -eu
CACHE=${1:?usage: prepare.sh CACHE_DIR}
mkdir -p "$CACHE"
CACHE=$(cd "$CACHE" && pwd)
# The cache is stamped with this script's hash: an edited guest init rebuilds the initramfs.
STAMP=$(sha256sum "$0" | cut -c1-16)
if [ "$(cat "$CACHE/ready" 2>/dev/null)" = "$STAMP" ] && [ -f "$CACHE/vmlinuz" ] && [ -f "$CACHE/initramfs.gz" ]; then exit 0; fi

for tool in qemu-system-x86_64 busybox depmod dpkg-deb; do
  command -v "$tool" >/dev/null 2>&1 || { echo "SKIP: $tool not found (apt-get install qemu-system-x86 busybox-static kmod)"; exit 77; }
done
BUSYBOX=$(command -v busybox)
case "$(file -b "$BUSYBOX" 2>/dev/null || echo static)" in
  *dynamic*) [ -x /bin/busybox ] && BUSYBOX=/bin/busybox ;;
esac

# 1. kernel: the package linux-image-amd64 depends on.
if [ ! -f "$CACHE/kernel/ok" ]; then
  PKG=$(apt-cache depends linux-image-amd64 2>/dev/null | sed -n 's/^ *Depends: \(linux-image-[0-9].*\)$/\1/p' | head -n1)
  [ -n "$PKG" ] || { echo "SKIP: apt-cache cannot resolve linux-image-amd64"; exit 77; }
  rm -rf "$CACHE/kernel" "$CACHE/deb"; mkdir -p "$CACHE/kernel" "$CACHE/deb"
  (cd "$CACHE/deb" && apt-get download "$PKG" >/dev/null 2>&1) || { echo "SKIP: apt-get download $PKG failed (no network or mirror)"; exit 77; }
  dpkg -x "$CACHE"/deb/*.deb "$CACHE/kernel"
  VER=$(ls "$CACHE/kernel/lib/modules" | head -n1)
  depmod -b "$CACHE/kernel" "$VER"
  echo "$VER" > "$CACHE/kernel/ok"
  rm -rf "$CACHE/deb"
fi
VER=$(cat "$CACHE/kernel/ok")
cp "$CACHE/kernel/boot/vmlinuz-$VER" "$CACHE/vmlinuz"

# 2. initramfs: busybox, the modules (in load order), /init.
MODS="virtio_ring virtio virtio_pci_modern_dev virtio_pci_legacy_dev virtio_pci netfs fscache 9pnet 9pnet_virtio 9p can can-raw can-dev vcan"
ROOT="$CACHE/initramfs"
rm -rf "$ROOT"; mkdir -p "$ROOT/bin" "$ROOT/modules" "$ROOT/host" "$ROOT/proc" "$ROOT/sys" "$ROOT/dev"
cp "$BUSYBOX" "$ROOT/bin/busybox"
for m in $MODS; do
  f=$(find "$CACHE/kernel/lib/modules/$VER" \( -name "$m.ko" -o -name "$m.ko.xz" -o -name "$(echo $m | tr - _).ko" -o -name "$(echo $m | tr - _).ko.xz" \) | head -n1)
  [ -n "$f" ] || { echo "module $m not found in $VER" >&2; exit 1; }
  case "$f" in
    *.xz) xz -dc "$f" > "$ROOT/modules/$m.ko" ;;
    *) cp "$f" "$ROOT/modules/$m.ko" ;;
  esac
done
echo "$MODS" > "$ROOT/modules/order"
cat > "$ROOT/init" <<'INIT'
#!/bin/busybox sh
/bin/busybox --install -s /bin
export PATH=/bin
mount -t proc proc /proc; mount -t sysfs sys /sys; mount -t devtmpfs dev /dev 2>/dev/null
for m in $(cat /modules/order); do insmod /modules/$m.ko || echo "VMINIT: insmod $m failed"; done
mount -t 9p -o trans=virtio,version=9p2000.L,msize=262144 hostroot /host || { echo "VMINIT: 9p mount failed"; poweroff -f; }
mount -t proc proc /host/proc; mount -t sysfs sys /host/sys; mount -t devtmpfs dev /host/dev 2>/dev/null || mount --bind /dev /host/dev
mkdir -p /host/dev/shm && mount -t tmpfs tmp /host/dev/shm 2>/dev/null
ip link set lo up
ip link add dev vcan0 type vcan && ip link set vcan0 mtu 72 && ip link set up vcan0
ip link add dev vcan1 type vcan && ip link set up vcan1
CMDFILE=$(sed -n 's/.*vecmd=\([^ ]*\).*/\1/p' /proc/cmdline)
if [ -n "$CMDFILE" ] && [ -f "/host$CMDFILE" ]; then
  chroot /host /bin/sh "$CMDFILE"
  echo "VMINIT: command exited with $?"
else
  echo "VMINIT: no command file ($CMDFILE)"
fi
sync
poweroff -f
INIT
chmod +x "$ROOT/init"
(cd "$ROOT" && find . | "$BUSYBOX" cpio -o -H newc 2>/dev/null | gzip -1 > "$CACHE/initramfs.gz")
echo "$STAMP" > "$CACHE/ready"
