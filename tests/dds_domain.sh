# DDS domain ids for test scripts: the shell side of tests/integration/test_domain.hpp
# (read it for the scheme). Source this file, then
#   ve_reserve_dds_domain || exit 1
# sets VE_DDS_DOMAIN to a domain of the pool (VE_TEST_DDS_DOMAINS, default 1-60) that
# no other test process on this host holds, and keeps it on file descriptor 9 (an
# exclusive flock on /tmp/ve-test-dds-domains/D.lock) for this shell and every process
# it starts, until the last of them has ended. Stale Fast DDS shared-memory port files
# of the domain's ports are removed first.

ve_reserve_dds_domain() {
  _ve_dir=/tmp/ve-test-dds-domains
  if mkdir "$_ve_dir" 2>/dev/null; then chmod 1777 "$_ve_dir" 2>/dev/null; fi
  _ve_pool=${VE_TEST_DDS_DOMAINS:-1-60}
  _ve_first=${_ve_pool%-*}
  _ve_last=${_ve_pool#*-}
  case "$_ve_first$_ve_last" in
    '' | *[!0-9]*) echo "VE_TEST_DDS_DOMAINS='$_ve_pool': expected FIRST-LAST" >&2; return 1 ;;
  esac
  if [ "$_ve_first" -gt "$_ve_last" ] || [ "$_ve_last" -gt 232 ]; then
    echo "VE_TEST_DDS_DOMAINS='$_ve_pool': expected FIRST-LAST with 0 <= FIRST <= LAST <= 232" >&2
    return 1
  fi
  _ve_n=$((_ve_last - _ve_first + 1))
  _ve_start=$(( ($$ + $(od -An -N2 -tu2 /dev/urandom | tr -d ' ')) % _ve_n ))
  _ve_tries=0
  while [ "$_ve_tries" -lt 600 ]; do  # 600 x 0.2 s: up to two minutes for a free one
    _ve_i=0
    while [ "$_ve_i" -lt "$_ve_n" ]; do
      _ve_d=$((_ve_first + (_ve_start + _ve_i) % _ve_n))
      _ve_lock="$_ve_dir/$_ve_d.lock"
      if [ ! -e "$_ve_lock" ]; then : >"$_ve_lock" 2>/dev/null && chmod 666 "$_ve_lock" 2>/dev/null; fi
      if exec 9<"$_ve_lock"; then
        if flock -n 9; then
          VE_DDS_DOMAIN=$_ve_d
          _ve_remove_stale_shm_ports "$_ve_d"
          return 0
        fi
        exec 9<&-
      fi
      _ve_i=$((_ve_i + 1))
    done
    _ve_tries=$((_ve_tries + 1))
    sleep 0.2
  done
  echo "no free DDS domain in $_ve_pool (locks in $_ve_dir)" >&2
  return 1
}

# The Fast DDS shared-memory port files of domain $1's ports (7400 + 250 d ... + 249).
_ve_remove_stale_shm_ports() {
  _ve_lo=$((7400 + 250 * $1))
  _ve_hi=$((_ve_lo + 250))
  for _ve_f in /dev/shm/fastrtps_port* /dev/shm/sem.fastrtps_port*; do
    [ -e "$_ve_f" ] || continue
    _ve_p=$(basename "$_ve_f" | sed -n 's/^\(sem\.\)\{0,1\}fastrtps_port\([0-9]\{1,6\}\)\(_el\|_sl\|_mutex\)\{0,1\}$/\2/p')
    [ -n "$_ve_p" ] || continue
    if [ "$_ve_p" -ge "$_ve_lo" ] && [ "$_ve_p" -lt "$_ve_hi" ]; then rm -f "$_ve_f"; fi
  done
}
