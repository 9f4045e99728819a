#!/usr/bin/env bash
# `make test`: lint and type checks, the lock-step tests beside the socketcan lane, then the
# tests that need the machine to themselves; each part's wall time goes to OUT/test-times.txt.
#
#   tests/lanes.sh BIN OUT
#
# * The socketcan lane (tests/hil/test_socketcan_lane.py) boots a one-CPU user-mode Linux
#   guest for 3-4 minutes: it starts first and runs beside lint and the lock-step tests.
# * Lock-step tests (every test not marked `alone`) do not mind a shared machine: two
#   pytest-xdist workers.  A module whose tests share one expensive fixture keeps them on one
#   worker (`xdist_group`, --dist loadgroup).
# * Tests marked `alone` (real time, or a count of the kernel's drops) run after everything
#   else, two at a time: each real-time run uses about half a core (its processes mostly wait
#   for the clock), so two of them leave the machine idle more than busy.
# Exit status: 0 when every part passed.
set -uo pipefail
BIN=${1:?usage: tests/lanes.sh BIN OUT}
OUT=${2:?usage: tests/lanes.sh BIN OUT}
LANE_TEST=tests/hil/test_socketcan_lane.py
mkdir -p "$OUT"
TIMES=$OUT/test-times.txt
: > "$TIMES"
PYTEST=("$BIN/python" -m pytest -q -p no:cacheprovider)

t0=$SECONDS
echo "socketcan lane: $LANE_TEST beside lint and the lock-step tests, output in $OUT/socketcan-lane.log"
(
    "${PYTEST[@]}" --basetemp="$OUT/socketcan-lane-tmp" "$LANE_TEST" > "$OUT/socketcan-lane.log" 2>&1
    echo $? > "$OUT/socketcan-lane.rc"
    echo $((SECONDS - t0)) > "$OUT/socketcan-lane.s"
) &
lane=$!

t=$SECONDS
"$BIN/ruff" check . && "$BIN/ruff" format --check . && "$BIN/mypy"
lint_rc=$?
echo "lint $((SECONDS - t))" >> "$TIMES"

t=$SECONDS
"${PYTEST[@]}" -n 2 --dist loadgroup -m "not alone" --deselect "$LANE_TEST" tests
lockstep_rc=$?
echo "lock-step $((SECONDS - t))" >> "$TIMES"

wait $lane
lane_rc=$(cat "$OUT/socketcan-lane.rc" 2>/dev/null || echo 1)
echo "socketcan-lane $(cat "$OUT/socketcan-lane.s" 2>/dev/null || echo "?")" >> "$TIMES"
echo "--- socketcan lane ($LANE_TEST), exit $lane_rc:"
cat "$OUT/socketcan-lane.log"

t=$SECONDS
"${PYTEST[@]}" -n 2 --dist loadgroup -m alone tests
alone_rc=$?
echo "alone $((SECONDS - t))" >> "$TIMES"
echo "tests $((SECONDS - t0))" >> "$TIMES"

echo "test: $(awk '{printf "%s%s %s s", (NR > 1 ? ", " : ""), $1, $2}' "$TIMES")" \
    "(lint $lint_rc, lock-step $lockstep_rc, socketcan lane $lane_rc, alone $alone_rc)"
test "$lint_rc" -eq 0 && test "$lockstep_rc" -eq 0 && test "$lane_rc" -eq 0 && test "$alone_rc" -eq 0
