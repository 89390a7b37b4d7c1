#!/usr/bin/env bash
# Installs a machine file as the one the systemd unit runs, /etc/virtual-encoder/machine.yaml,
# with the files it refers to still found from there.
#
#   deploy/install-machine.sh [--root DIR] [--force] [--no-check] MACHINE.yaml
#
# A machine file names its motor, calibration, CAN layout, replay log and DDS profiles by
# paths relative to itself (`motor: ../motors/sim-12mm.yaml`). A plain copy to
# /etc/virtual-encoder would look for them in /etc/motors/. This copy rewrites each such
# relative path to the absolute path of the file it named beside MACHINE.yaml, for example
# /usr/share/virtual-encoder/config/motors/sim-12mm.yaml for a shipped machine; nothing else
# changes. A commented-out reference (`# calibration: ../calibration/x.cal.yaml`) is rewritten
# too when the file it names exists, so uncommenting it later works. A relative
# `homing.state_file` is left alone with a warning: the service can write only under
# /var/lib/virtual-encoder, so give it an absolute path there.
#
#   --root DIR   install under DIR instead of / (DIR/etc/virtual-encoder/machine.yaml)
#   --force      replace an existing machine.yaml (it is kept otherwise: it may have been edited)
#   --no-check   do not run `virtual-encoder check` on the result
#
# Then the installed file is checked with `virtual-encoder check --config` (the binary under
# DIR/usr/bin, else the one on PATH). Exit codes: 0 installed (and checked); 1 the check
# found problems (the file stays, to be edited); 2 bad arguments, or nothing was written.
set -euo pipefail

root=""
force=0
check=1
src=""
usage() { echo "usage: deploy/install-machine.sh [--root DIR] [--force] [--no-check] MACHINE.yaml" >&2; exit 2; }
while [ $# -gt 0 ]; do
  case "$1" in
    --root) [ $# -ge 2 ] || usage; root="${2%/}"; shift 2 ;;
    --force) force=1; shift ;;
    --no-check) check=0; shift ;;
    -h|--help) sed -n '2,22s/^# \{0,1\}//p' "$0"; exit 0 ;;
    -*) echo "install-machine: unknown option '$1'" >&2; usage ;;
    *) [ -z "$src" ] || usage; src="$1"; shift ;;
  esac
done
[ -n "$src" ] || usage
if [ ! -f "$src" ] || [ ! -r "$src" ]; then
  echo "install-machine: cannot read the machine file '$src'" >&2
  exit 2
fi

etc="$root/etc/virtual-encoder"
dest="$etc/machine.yaml"
if [ -e "$dest" ] && [ "$force" -eq 0 ]; then
  echo "install-machine: $dest exists; --force replaces it" >&2
  exit 2
fi
srcdir="$(cd "$(dirname "$src")" && pwd -P)"
mkdir -p "$etc"
tmp="$(mktemp "$etc/.machine.yaml.XXXXXX")"
trap 'rm -f "$tmp"' EXIT

# Keys whose value is a file the loader reads, relative to the machine file.
keys='motor|calibration|layout|log|profiles_file'
re="^([[:space:]]*(#[[:space:]]*)?(-[[:space:]]+)?($keys):[[:space:]]*)([\"']?)([^\"'[:space:]#]+)([\"']?)(.*)$"
state_re="^[[:space:]]*(-[[:space:]]+)?state_file:[[:space:]]*[\"']?([^\"'[:space:]#]+)"
rewritten=0
lineno=0
while IFS= read -r line || [ -n "$line" ]; do
  lineno=$((lineno + 1))
  if [[ "$line" =~ $re ]]; then
    head="${BASH_REMATCH[1]}" commented="${BASH_REMATCH[2]}" q1="${BASH_REMATCH[5]}"
    path="${BASH_REMATCH[6]}" q2="${BASH_REMATCH[7]}" tail="${BASH_REMATCH[8]}"
    if [[ "$path" != /* ]]; then
      abs="$(realpath -m "$srcdir/$path")"
      if [ -z "$commented" ] || [ -e "$abs" ]; then
        line="$head$q1$abs$q2$tail"
        rewritten=$((rewritten + 1))
      fi
    fi
  elif [[ "$line" =~ $state_re ]] && [[ "${BASH_REMATCH[2]}" != /* ]]; then
    echo "install-machine: $src:$lineno: homing.state_file '${BASH_REMATCH[2]}' is relative: it would be $etc/${BASH_REMATCH[2]}, which the service cannot write; use an absolute path under /var/lib/virtual-encoder/" >&2
  fi
  printf '%s\n' "$line"
done <"$src" >"$tmp"
chmod 0644 "$tmp"
mv -f "$tmp" "$dest"
trap - EXIT
echo "install-machine: $dest from $src ($rewritten relative file references made absolute)"

[ "$check" -eq 1 ] || exit 0
bin="$root/usr/bin/virtual-encoder"
[ -x "$bin" ] || bin="$(command -v virtual-encoder || true)"
if [ -z "$bin" ]; then
  echo "install-machine: virtual-encoder not found; not checked (run: virtual-encoder check --config $dest)" >&2
  exit 0
fi
if "$bin" check --config "$dest"; then
  exit 0
fi
echo "install-machine: $dest has problems (above); edit it, then: virtual-encoder check --config $dest" >&2
exit 1
