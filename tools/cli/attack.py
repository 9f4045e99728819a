"""Arguments of ``wheelchair-hil attack`` and its action: the bus attacks of docs/safety.md on
real-time runs across processes, with and without authentication, and the authentication's
cost per tick."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING

from tools.cli.options import controller_name
from tools.safety.attacks.attacker import ATTACKS

if TYPE_CHECKING:
    from tools.safety.attacks.analysis import AttackResult


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--attack", action="append", choices=ATTACKS, help="default: all")
    p.add_argument("--auth", choices=("on", "off", "both"), default="both")
    p.add_argument("--scenario", default="fault-free")
    p.add_argument("--controller", type=controller_name, default="antifragile", metavar="NAME")
    p.add_argument("--at", type=float, default=8.0, help="attack onset, simulated s")
    p.add_argument("--duration", type=float, default=16.0, help="simulated s per run")
    p.add_argument(
        "--false-alarms",
        type=int,
        default=0,
        metavar="N",
        help="instead: N real-time runs without an attack; count plausibility stops",
    )
    p.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        metavar="N",
        help="SCHED_FIFO priority of the controller (the bench gets N+1), as on a chair; 0: none",
    )
    p.add_argument("--cost", action="store_true", help="only the auth cost per tick")
    p.add_argument("--out", required=False, default="out/attacks")
    p.add_argument("--json", action="store_true", help="print the results as JSON")


def _fmt(v: float | None, nd: int = 2) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """The authentication's cost per tick, then (unless ``--cost``) the attacks or the
    fault-free runs, a line each; 0 when every one passed."""
    from tools.safety.attacks import runs  # lazy: the stack
    from tools.safety.attacks.cost import auth_cost  # lazy

    cost = auth_cost()
    print(
        f"MAC {cost['mac_bits']:.0f} bits (HMAC-SHA256 truncated); per tick: host "
        f"{cost['host_auth_us_per_tick']:.1f} us more for its two setpoints "
        f"({cost['host_encode_secured_us_per_tick']:.1f} us secured against "
        f"{cost['host_encode_plain_us_per_tick']:.1f} us plain), drive "
        f"{cost['drive_verify_us_per_frame']:.1f} us to check its setpoint (medians)"
    )
    if args.cost:
        return 0
    out = Path(args.out)
    modes = {"on": [True], "off": [False], "both": [True, False]}[args.auth]
    if args.false_alarms:
        return false_alarms(args, out, modes)
    results = []
    for res in runs.campaign(
        out,
        args.attack or ATTACKS,
        modes,
        scenario=args.scenario,
        controller=args.controller,
        at_s=args.at,
        duration_s=args.duration,
        rt_priority=args.rt_priority,
    ):
        results.append(res)
        print(_line(res), flush=True)
    (out / "attacks.json").write_text(json.dumps([r.as_dict() for r in results], indent=2))
    if args.json:
        print(json.dumps([r.as_dict() for r in results], indent=2))
    return 0 if all(r.passed for r in results) else 1


def _line(r: AttackResult) -> str:
    total: dict[str, int] = {}
    for d in r.refusals.values():
        for k, v in d.items():
            total[k] = total.get(k, 0) + v
    top = ", ".join(f"{k} {v}" for k, v in sorted(total.items(), key=lambda kv: -kv[1])[:4])
    return (
        f"{r.attack:14s} auth {'on ' if r.auth else 'off'}  peak {r.peak_speed_mps:.2f} m/s "
        f"{r.peak_yaw_radps:.2f} rad/s (route before: {r.route_peak_speed_mps:.2f}, "
        f"{r.route_peak_yaw_radps:.2f})  detected {_fmt(r.detected_s)} s {r.detection or '-'}; "
        f"host {r.host_final_state} {r.stop_reason}; after stop "
        f"{_fmt(r.wheel_after_stop_revps, 3)} rev/s; refused: {top or '-'}  "
        f"{'PASS' if r.passed else 'FAIL: ' + '; '.join(r.failures)}"
    )


def false_alarms(args: argparse.Namespace, out: Path, modes: list[bool]) -> int:
    """``--false-alarms N``: N fault-free real-time runs per mode, a line each and the count of
    plausibility stops; 0 when none stopped for plausibility and every run was valid."""
    from tools.safety.attacks import runs  # lazy: the stack

    trips = invalid = early = 0
    worst: list[float] = []
    for k, auth, res in runs.false_alarm_runs(
        out,
        args.false_alarms,
        modes,
        scenario=args.scenario,
        controller=args.controller,
        at_s=args.at,
        duration_s=args.duration,
        rt_priority=args.rt_priority,
    ):
        w = math.nan if res.obey_worst_revps is None else res.obey_worst_revps
        worst.append(w)
        tripped = res.stop_reason == "DISOBEYED"
        trips += tripped
        invalid += bool(res.failures and res.failures[0].startswith("invalid run"))
        early += res.detected_s is not None
        stopped = (
            f"stopped {res.detected_s:.2f} s after {args.at:g} s: {res.detection}"
            if res.detected_s is not None
            else "no stop before the bench ended"
        )
        print(
            f"run {k} auth {'on' if auth else 'off'}: {stopped}; host at the end "
            f"{res.host_final_state} {res.stop_reason}; closest to the plausibility bound "
            f"{w:.4f} rev/s ({res.run_dir})",
            flush=True,
        )
    print(
        f"plausibility stops in {len(worst)} fault-free real-time runs: {trips}; "
        f"runs that stopped for any reason before the bench ended: {early}"
        + (
            f" ({invalid} of them invalid: the host was not tracking at {args.at:g} s)"
            if invalid
            else ""
        )
    )
    return 0 if trips == 0 and invalid == 0 else 1
