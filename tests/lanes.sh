#!/usr/bin/env bash
# `make test`: lint and type checks and the lock-step tests beside the socketcan lane, then the
# tests that need the machine to themselves; each part's wall time goes to OUT/test-times.txt.
#
#   tests/lanes.sh BIN OUT
#
# * The socketcan lane (tests/hil/test_socketcan_lane.py) boots a one-CPU user-mode Linux
#   guest for 3-4 minutes (on SCHED_FIFO where root: tools/bus/umlguest.py): it starts first
#   and runs beside lint (itself beside the first tests) and the lock-step tests, all in one
#   pytest session: tests/integration, tests/unit, then the multi-process lock-step tests of
#   tests/hil and tests/safety (not marked `alone`), none of which minds sharing the
#   machine.  They run on two pytest-xdist workers, a file's tests on one worker (--dist
#   loadfile): a module's fixture is built once (test_stop_signals's, 140 s of runs; the
#   wheel and its venv, which under --dist load one worker waited 30 s for while the other
#   built them), and the heaviest files go first (those that declare `heavy`, heaviest first:
#   tests/conftest.py; --no-loadscope-reorder keeps that order, where pytest-xdist's own, most
#   tests first, left the README's install block among the last files), so that they are not
#   the last left while the other worker idles (--dist load to loadfile, the conformance
#   runs split in two files: unit and integration 321 s to 295 s, 582 to 520 worker-s, on a
#   quiet machine).  (pytest-xdist 3.8's loadgroup does not group
#   under pytest 9.2: it sets a node id attribute pytest no longer reads.)  They share the
#   core the guest leaves while it runs, and take both once it ends.
# * Once the guest has ended, beside the lock-step tests still running, the tests marked
#   `alone` and `paired` two at a time, a file's tests on one worker (its module fixture
#   built once), in the order tests/conftest.py gives them (the files that declare their
#   length first, longest first; not pytest-xdist's, most tests first, which started the
#   3-minute soak, one test, behind the others): the soak, the attacks, the killed or
#   stopped controller, the recorder killed, can_player, the doctor against a real-time
#   bench, the Foxglove client.  Real time, but judged in simulation time from their own
#   logs, or by what arrives, their parts on SCHED_FIFO where root (tests/rt.py; all passed
#   beside two spinning processes), so lock-step work beside them changes nothing they judge.
# * Last, alone, the other tests marked `alone`: the fuzz test, whose lock-step run must
#   lose no frame of its own to the kernel while 100,000 datagrams flood it (beside two
#   spinning processes it took 63 s against 25 s alone).
# Exit status: 0 when every part passed.
set -uo pipefail
BIN=${1:?usage: tests/lanes.sh BIN OUT}
OUT=${2:?usage: tests/lanes.sh BIN OUT}
LANE_TEST=tests/hil/test_socketcan_lane.py
mkdir -p "$OUT"
TIMES=$OUT/test-times.txt
: > "$TIMES"
rm -f "$OUT/socketcan-lane.rc" "$OUT/socketcan-lane.s" "$OUT/paired.rc" "$OUT/paired.s"
rm -f "$OUT"/junit-*.xml
PYTEST=("$BIN/python" -m pytest -q -rsx -p no:cacheprovider --durations=20)
# cpu_s NAME: the CPU seconds (user and system) of what this (sub)shell has run and waited
# for, into $OUT/NAME.cpu: the third column of test-times.txt, beside the wall time (what a part
# costs the machine, not only the critical path).  `times` in this shell, not in a $(...)
# subshell, which has waited for nothing.
cpu_s() {
    times > "$OUT/$1.times"
    awk 'NR == 2 { split($1, u, /[ms]/); split($2, s, /[ms]/)
        printf "%.0f", u[1] * 60 + u[2] + s[1] * 60 + s[2] }' "$OUT/$1.times" > "$OUT/$1.cpu"
}

t0=$SECONDS
echo "socketcan lane: $LANE_TEST beside the lock-step tests, output in $OUT/socketcan-lane.log"
(
    "${PYTEST[@]}" -rsxP --basetemp="$OUT/socketcan-lane-tmp" --junitxml="$OUT/junit-socketcan-lane.xml" \
        "$LANE_TEST" > "$OUT/socketcan-lane.log" 2>&1
    echo $? > "$OUT/socketcan-lane.rc"
    cpu_s socketcan-lane
    echo "$((SECONDS - t0)) $(cat "$OUT/socketcan-lane.cpu")" > "$OUT/socketcan-lane.s"
) &
lane=$!

# the paired real-time tests, as soon as the guest has ended
(
    until [ -e "$OUT/socketcan-lane.rc" ]; do sleep 1; done
    t=$SECONDS
    "${PYTEST[@]}" --basetemp="$OUT/paired-tmp" -n 2 --dist loadfile --no-loadscope-reorder -m "alone and paired" \
        --junitxml="$OUT/junit-paired.xml" tests/hil tests/safety > "$OUT/paired.log" 2>&1
    echo $? > "$OUT/paired.rc"
    cpu_s paired
    echo "$((SECONDS - t)) $(cat "$OUT/paired.cpu")" > "$OUT/paired.s"
) &
paired=$!

# lint and type checks beside the first tests (about 30 s of one core, off the critical path)
rm -f "$OUT/lint.rc"
(
    t=$SECONDS
    { "$BIN/ruff" check . && "$BIN/ruff" format --check . && "$BIN/mypy"; } > "$OUT/lint.log" 2>&1
    echo $? > "$OUT/lint.rc"
    cpu_s lint
    echo "lint $((SECONDS - t)) $(cat "$OUT/lint.cpu")" >> "$TIMES"
) &
lint=$!

# every lock-step test in one session: neither worker idles at the end of one stage while
# the other finishes its last file (the hil tests last: by then the guest has ended)
(
    t=$SECONDS
    "${PYTEST[@]}" -n 2 --dist loadfile --no-loadscope-reorder -m "not alone" --deselect "$LANE_TEST" \
        --junitxml="$OUT/junit-lock-step.xml" tests/integration tests/unit tests/hil tests/safety
    rc=$?
    cpu_s lock-step
    echo "lock-step $((SECONDS - t)) $(cat "$OUT/lock-step.cpu")" >> "$TIMES"
    exit $rc
)
lockstep_rc=$?
wait $lint
lint_rc=$(cat "$OUT/lint.rc" 2>/dev/null || echo 1)
echo "--- lint and type checks (ruff, mypy), exit $lint_rc:"
cat "$OUT/lint.log"

wait $lane
lane_rc=$(cat "$OUT/socketcan-lane.rc" 2>/dev/null || echo 1)
echo "socketcan-lane $(cat "$OUT/socketcan-lane.s" 2>/dev/null || echo "?")" >> "$TIMES"
echo "--- socketcan lane ($LANE_TEST), exit $lane_rc:"
cat "$OUT/socketcan-lane.log"

wait $paired
paired_rc=$(cat "$OUT/paired.rc" 2>/dev/null || echo 1)
echo "paired $(cat "$OUT/paired.s" 2>/dev/null || echo "?")" >> "$TIMES"
echo "--- alone and paired (two at a time, beside the lock-step tests), exit $paired_rc:"
cat "$OUT/paired.log"

# (tests/unit and tests/integration hold no `alone` test: nothing there is collected again)
(
    t=$SECONDS
    "${PYTEST[@]}" -m "alone and not paired" --junitxml="$OUT/junit-alone.xml" tests/hil tests/safety
    rc=$?
    cpu_s alone
    echo "alone $((SECONDS - t)) $(cat "$OUT/alone.cpu")" >> "$TIMES"
    exit $rc
)
alone_rc=$?
cpu_s tests
echo "tests $((SECONDS - t0)) $(cat "$OUT/tests.cpu")" >> "$TIMES"

# each part's wall time, and in brackets the CPU time of its processes
echo "test: $(awk '{printf "%s%s %s s", (NR > 1 ? ", " : ""), $1, $2; if (NF > 2) printf " (cpu %s s)", $3}' "$TIMES")" \
    "(exit: lint $lint_rc, lock-step $lockstep_rc, socketcan lane $lane_rc," \
    "paired $paired_rc, alone $alone_rc)"
# the skipped tests of every part (in CI each is one that tests/conftest.py's ALLOWED_SKIPS
# allows) and, apart, the expected failures (junit writes both as <skipped>; an xfail's type
# is pytest.xfail): neither is a pass, so the last line counts each
"$BIN/python" - "$OUT" <<'PY'
import sys, xml.etree.ElementTree as ET
from pathlib import Path
skipped = xfailed = 0
for f in sorted(Path(sys.argv[1]).glob("junit-*.xml")):
    for s in ET.parse(f).getroot().iter("skipped"):
        if s.get("type") == "pytest.xfail":
            xfailed += 1
        else:
            skipped += 1
Path(sys.argv[1], "skipped.txt").write_text(f"{skipped} {xfailed}\n")
print(f"test: {skipped} skipped, {xfailed} expected failures (their reasons: the -rsx lines above)")
PY
for rc in "$lint_rc" "$lockstep_rc" "$lane_rc" "$paired_rc" "$alone_rc"; do
    test "$rc" -eq 0 || exit 1
done
