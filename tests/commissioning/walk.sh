#!/bin/sh
# The commissioning walk: follows docs/commissioning.md and nothing else.
#
# Every fenced ```sh block of the guide that follows a marker line
#     <!-- walk: NAME -->        a step that runs here
#     <!-- walk: NAME can -->    a step that needs the CAN interface
# is a step. The steps run in the guide's order, each with `sh -e` in $WORK, until
# one fails. The build host's kernel has no CAN, so consecutive `can` steps run in
# one boot of the SocketCAN VM (tests/vm: a Debian kernel with vcan0 up, the host's
# root shared over 9p, so the same paths and files); the other steps (files,
# calibration, evaluation: computation that is slow under an emulated CPU) run here,
# each group in a process group of its own that ends with this script. The only
# substitution is the four variables the guide's rehearsal asks the reader to set:
#     WORK    a fresh directory of this run
#     CAN     vcan0 (the VM's CAN FD capable vcan)
#     DOMAIN  a DDS domain reserved for this run (tests/dds_domain.sh)
#     CONFIG  the source tree's config/ (the shipped files)
# and `virtual-encoder` on PATH is the built binary. Then each step's outcome is
# checked: the files it writes, the verdicts, exit codes and what `monitor` saw.
#
# Usage: walk.sh SOURCE_DIR BINARY VM_CACHE OUT_PARENT
# Exit: 0 passed; 1 failed (the reason, each step's log and the console are printed);
# 77 the VM cannot run here (skipped, saying why).
set -u
SRC=$(cd "${1:?usage: walk.sh SOURCE_DIR BINARY VM_CACHE OUT_PARENT}" && pwd)
BIN=${2:?binary}
CACHE=${3:?vm cache}
PARENT=${4:?output parent}
GUIDE=$SRC/docs/commissioning.md

mkdir -p "$PARENT" "$CACHE"
# A fresh directory per run: two runs of one build tree may each boot a VM.
OUT=$(mktemp -d "$PARENT/walk.XXXXXX") || exit 1
OUT=$(cd "$OUT" && pwd)
WORK=$OUT/work
STEPS=$OUT/steps
mkdir -p "$WORK" "$STEPS" "$OUT/bin" "$OUT/logs" "$OUT/rc"
ln -s "$BIN" "$OUT/bin/virtual-encoder"
echo "walk: output in $OUT"

fail() {
  echo "FAIL: $*"
  for f in "$OUT"/logs/*.log; do
    [ -f "$f" ] || continue
    echo "---- $(basename "$f") ----"
    tail -n 60 "$f"
  done
  for c in "$OUT"/console*.log; do [ -f "$c" ] && { echo "---- $(basename "$c") (last lines) ----"; tail -n 30 "$c"; }; done
  exit 1
}

# ---- 1. The steps, extracted from the guide.
awk -v dir="$STEPS" '
  /^<!-- walk: / {
    if (want) { print "marker for " name " at line " marker_line " is not followed by a ```sh block" > "/dev/stderr"; bad = 1 }
    name = $3; where = ($4 == "can") ? "can" : "host"; want = 1; marker_line = NR; next
  }
  want && /^```sh[ \t]*$/ { n++; f = sprintf("%s/%02d-%s.%s", dir, n, name, where); printf "" > f; infence = 1; want = 0; next }
  infence && /^```[ \t]*$/ { infence = 0; close(f); next }
  infence { print >> f; next }
  want && NF { print "marker for " name " at line " marker_line " is followed by text, not a ```sh block" > "/dev/stderr"; bad = 1; want = 0 }
  END { if (infence) { print "unterminated ```sh block of " name > "/dev/stderr"; bad = 1 } exit bad }
' "$GUIDE" || fail "docs/commissioning.md: the walk markers are malformed"
ls "$STEPS" > "$OUT/step-list"
[ -s "$OUT/step-list" ] || fail "docs/commissioning.md has no <!-- walk: NAME --> steps"
# The walk must cover the whole procedure: these steps are checked below.
for want in motor machine node bus check-wiring record-sweep record-fast record-accept ruler \
            calibrate-ruler calibrate-no-ruler install-calibration evaluate check-calibrated run-monitor; do
  grep -q "^[0-9][0-9]-$want\.\(can\|host\)\$" "$OUT/step-list" || fail "docs/commissioning.md has no walk step '$want'"
done
echo "walk: $(wc -l < "$OUT/step-list") steps from docs/commissioning.md:"
sed 's/^/  /' "$OUT/step-list"

# ---- 2. The VM.
flock "$CACHE.lock" sh "$SRC/tests/vm/prepare.sh" "$CACHE" > "$OUT/prepare.log" 2>&1
p=$?
if [ $p -eq 77 ]; then echo "SKIPPED: $(cat "$OUT/prepare.log")"; exit 77; fi
[ $p -eq 0 ] || fail "tests/vm/prepare.sh: $(cat "$OUT/prepare.log")"

# ---- 3. The DDS domain of this run (held on fd 9 by this shell and every child; the
# guest's network is its own loopback, but no test uses a domain it has not reserved).
. "$SRC/tests/dds_domain.sh"
ve_reserve_dds_domain || fail "no DDS domain"
echo "walk: DDS domain $VE_DDS_DOMAIN"

# ---- 4. Run the steps, group by group. A group script runs its steps in order and
# stops at the first that fails; each step's output goes to logs/NAME.log, its exit
# code to rc/NAME.
write_group() {  # FILE STEP...
  file=$1; shift
  {
    echo "#!/bin/sh"
    echo "export PATH=$OUT/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin HOME=$OUT"
    echo "export WORK=$WORK CAN=vcan0 DOMAIN=$VE_DDS_DOMAIN CONFIG=$SRC/config"
    for st in "$@"; do
      name=${st#??-}; name=${name%.*}
      echo "echo \"$name: start \$(date +%s)\" >> $OUT/timing"
      echo "(cd \"\$WORK\" && exec sh -e $STEPS/$st) > $OUT/logs/$name.log 2>&1"
      echo "rc=\$?; echo \$rc > $OUT/rc/$name; echo \"$name: exit \$rc \$(date +%s)\" >> $OUT/timing"
      echo "[ \$rc -eq 0 ] || { sync; exit 1; }"
    done
    echo "sync"
  } > "$file"
}
GROUP_PID=""
cleanup() { [ -n "$GROUP_PID" ] && kill -KILL -- "-$GROUP_PID" 2>/dev/null; GROUP_PID=""; }
trap cleanup EXIT
trap 'cleanup; exit 143' TERM
trap 'cleanup; exit 130' INT

T0=$(date +%s)
g=0
set -- $(cat "$OUT/step-list")
while [ $# -gt 0 ]; do
  where=${1##*.}
  group=""
  while [ $# -gt 0 ] && [ "${1##*.}" = "$where" ]; do group="$group $1"; shift; done
  g=$((g + 1))
  write_group "$OUT/group$g.sh" $group
  t=$(date +%s)
  if [ "$where" = can ]; then
    # qemu ends with this script (run_in_vm.sh: setpriv --pdeathsig, timeout --foreground).
    # A VM that does not finish (on a loaded host the emulated guest's kernel has been seen
    # to lock up a CPU, "soft lockup" on its console) is booted once more for the same
    # steps, saying so; a step that fails is never retried.
    for attempt in 1 2; do
      for st in $group; do name=${st#??-}; rm -f "$OUT/rc/${name%.*}"; done
      setpriv --pdeathsig KILL sh "$SRC/tests/vm/run_in_vm.sh" "$CACHE" "$OUT/group$g.sh" 180 > "$OUT/vm$g.log" 2>&1
      r=$?
      [ -f "$OUT/console.log" ] && mv "$OUT/console.log" "$OUT/console$g-$attempt.log"
      if [ $r -eq 77 ]; then echo "SKIPPED: $(cat "$OUT/vm$g.log")"; exit 77; fi
      echo "walk: VM boot $g ($group ) $(($(date +%s) - t)) s"
      [ $r -eq 0 ] && break
      [ $attempt -eq 1 ] || fail "the VM, twice: $(cat "$OUT/vm$g.log")"
      echo "walk: the VM did not finish ($(cat "$OUT/vm$g.log")); its console, last lines:"
      tail -n 5 "$OUT/console$g-$attempt.log" | tr -d '\033' | sed 's/^/  /'
      echo "walk: booting it once more for the same steps"
      t=$(date +%s)
    done
  else
    setsid setpriv --pdeathsig KILL sh "$OUT/group$g.sh" &
    GROUP_PID=$!
    wait "$GROUP_PID"
    cleanup
    echo "walk: on this host ($group ) $(($(date +%s) - t)) s"
  fi
  for st in $group; do
    name=${st#??-}; name=${name%.*}
    [ -f "$OUT/rc/$name" ] || fail "step $name did not run (or wrote no exit code)"
    [ "$(cat "$OUT/rc/$name")" = 0 ] || fail "step $name exited with $(cat "$OUT/rc/$name")"
  done
done
echo "walk: every step exited 0 in $(($(date +%s) - T0)) s; steps (start / exit code and time, s since the epoch):"
sed 's/^/  /' "$OUT/timing"

# ---- 5. What each step must have done.
has() {  # STEP PATTERN WHAT
  grep -q -- "$2" "$OUT/logs/$1.log" || fail "step $1: $3 (no '$2' in its output)"
}
rows() { grep -vc '^#' "$1" 2>/dev/null || echo 0; }
need_file() { [ -s "$WORK/$1" ] || fail "$1 was not written"; }

need_file motor.yaml
need_file machine.yaml
for m in sweep fast accept; do need_file node-$m.yaml; done
has check-wiring "OK: machine" "check of the wired machine did not pass"
has check-wiring "socketcan" "check does not name the socketcan driver"
has check-wiring "no calibration: nominal table" "check before calibration should run on the nominal table"
# Every sample the node sent was recorded: `record` listened before the motion began,
# and no frame was lost on the way.
for rec in sweep fast accept; do
  need_file $rec.csv
  sent=$(sed -n 's/^sensor-node: [0-9]* frames (\([0-9]*\) samples) sent.*/\1/p' "$OUT/logs/record-$rec.log")
  got=$(sed -n 's/^recorded \([0-9]*\) samples .*/\1/p' "$OUT/logs/record-$rec.log")
  [ -n "$sent" ] && [ -n "$got" ] || fail "step record-$rec: no sensor-node or record summary"
  [ "$sent" -eq "$got" ] || fail "step record-$rec: the node sent $sent samples, record wrote $got"
done
# The sweep is one round trip over the stroke (15.2 s at 4 kHz), the fast motion 3 s, the
# acceptance run 4 s: most of it must have been recorded.
[ "$(rows "$WORK/sweep.csv")" -gt 50000 ] || fail "sweep.csv has only $(rows "$WORK/sweep.csv") rows"
[ "$(rows "$WORK/fast.csv")" -gt 8000 ] || fail "fast.csv has only $(rows "$WORK/fast.csv") rows"
[ "$(rows "$WORK/accept.csv")" -gt 10000 ] || fail "accept.csv has only $(rows "$WORK/accept.csv") rows"
need_file cal.csv
grep -q 'ref_position_m' "$WORK/cal.csv" && fail "cal.csv (the recording) should have no ruler column"
for f in cal-ruler.csv accept-ruler.csv; do
  need_file $f
  grep -q '^t_s,.*,ref_position_m$' "$WORK/$f" || fail "$f has no ref_position_m column"
  [ "$(rows "$WORK/$f")" -eq "$(rows "$WORK/${f%-ruler.csv}.csv")" ] || fail "$f has not one ruler reading per recorded row"
done
# With the ruler: GOOD, and written with its report and plots.
has calibrate-ruler "method reference" "the calibration with a ruler did not use it"
has calibrate-ruler "^Verdict: GOOD" "the calibration with a ruler is not GOOD"
# Without it: a verdict, and the file written exactly when it is GOOD.
has calibrate-no-ruler "method no-reference" "the calibration without a ruler did not say so"
has calibrate-no-ruler "^Verdict: \(GOOD\|POOR\)" "the calibration without a ruler gave no verdict"
if grep -q "^Verdict: GOOD" "$OUT/logs/calibrate-no-ruler.log"; then
  modes="ruler noruler"
else
  has calibrate-no-ruler "^  - " "a POOR verdict without its reasons"
  has calibrate-no-ruler "calibration NOT written" "a POOR calibration must not be written"
  [ -e "$WORK/noruler/bench-x.cal.yaml" ] && fail "a POOR calibration was written"
  modes="ruler"
fi
for mode in $modes; do
  need_file $mode/bench-x.cal.yaml
  need_file $mode/bench-x.cal.yaml.report.txt
  grep -q "^Verdict: GOOD" "$WORK/$mode/bench-x.cal.yaml.report.txt" || fail "$mode: the report has no GOOD verdict"
  for plot in table-period table-all-periods residuals forward-backward; do
    need_file $mode/bench-x.cal.yaml.$plot.svg
  done
done
has check-calibrated "OK: machine" "check of the calibrated machine did not pass"
id=$(sed -n 's/^id: *["'"'"']\{0,1\}\([0-9a-f]*\).*/\1/p' "$WORK/ruler/bench-x.cal.yaml")
[ -n "$id" ] || fail "ruler/bench-x.cal.yaml has no id"
has check-calibrated "calibration $id" "check does not name the installed calibration $id"
# The acceptance run against the ruler meets the product's 5 um target, and the
# consistency check finds it VALID nearly throughout.
has evaluate "against a reference ruler" "evaluate did not score against the ruler"
rms=$(sed -n 's/^  position error \[um\]: *rms *\([0-9.]*\).*/\1/p' "$OUT/logs/evaluate.log" | head -n 1)
[ -n "$rms" ] || fail "evaluate printed no position error"
awk -v r="$rms" 'BEGIN { exit !(r < 5.0) }' || fail "acceptance: position error $rms um RMS against the ruler (5 um or more)"
valid=$(sed -n 's/^  VALID: \([0-9.]*\) % of samples.*/\1/p' "$OUT/logs/evaluate.log" | head -n 1)
[ -n "$valid" ] || fail "evaluate's consistency check printed no VALID fraction"
awk -v v="$valid" 'BEGIN { exit !(v >= 95.0) }' || fail "acceptance: VALID in only $valid % of the samples"
echo "walk: acceptance against the ruler $rms um RMS; VALID $valid % of the samples"
need_file monitor.txt
need_file run.log
# monitor saw the axis publish VALID samples with the calibration in use, and the axis
# was homed (startup_position: from its first sample). In the emulated VM the estimator
# cannot keep up with 4 kHz and its ring overruns (run's driver line, not judged here);
# a gap that follows can cost HOMED later on, so HOMED is looked for in monitor's table or
# in run's status lines.
grep -Eq '^x\(1\) .*VALID\|CAL' "$WORK/monitor.txt" || fail "monitor shows no row of axis x(1) with VALID|CAL: $(tail -n 8 "$WORK/monitor.txt")"
grep -q 'VALID|CAL|HOMED' "$WORK/monitor.txt" "$WORK/run.log" || fail "neither monitor nor run showed VALID|CAL|HOMED"
grep -q 'x=.*\[VALID|CAL' "$WORK/run.log" || fail "run logged no VALID|CAL status line"
echo "walk: PASSED ($(($(date +%s) - T0)) s in all)"
exit 0
