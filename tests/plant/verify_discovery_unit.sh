#!/usr/bin/env bash
# systemd reads the Discovery Server's unit (deploy/discovery/fastdds-discovery@.service)
# without a complaint, as instance 0, with its profile and settings file at their source
# paths, and it runs /usr/bin/fastdds discovery. (The command line itself, with the profile,
# runs in tests/plant/discovery_server_test.sh.)
#   tests/plant/verify_discovery_unit.sh SOURCE_DIR
# Exit 0 verified; 1 a complaint (printed); 77 systemd-analyze or fastdds not installed.
set -u
SRC=${1:?usage: verify_discovery_unit.sh SOURCE_DIR}
command -v systemd-analyze >/dev/null || { echo "SKIPPED: systemd-analyze not installed"; exit 77; }
command -v fastdds >/dev/null || { echo "SKIPPED: fastdds (fastdds-tools) not installed"; exit 77; }
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
sed -e "s|/usr/share/virtual-encoder/discovery/server.xml|$SRC/deploy/discovery/server.xml|" \
    -e "s|EnvironmentFile=/etc/virtual-encoder/discovery-server-%i.env|EnvironmentFile=$SRC/deploy/discovery/discovery-server.env|" \
    "$SRC/deploy/discovery/fastdds-discovery@.service" >"$dir/fastdds-discovery@.service"
out=$(cd "$dir" && systemd-analyze verify "$dir/fastdds-discovery@0.service" 2>&1)
if [ -n "$out" ]; then echo "systemd-analyze verify:"; echo "$out"; exit 1; fi
grep -q '^ExecStart=/usr/bin/fastdds discovery ' "$SRC/deploy/discovery/fastdds-discovery@.service" ||
  { echo "ExecStart does not run /usr/bin/fastdds discovery"; exit 1; }
echo "fastdds-discovery@0.service verifies"
