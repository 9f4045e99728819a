"""Attack runs: one real-time run over udp_multicast in a private network namespace with an
attack (:func:`run_attack`: its configuration files, its processes, bench, controller,
recorder and the attacking node, repeated while the run is invalid), and a campaign of them
(:func:`campaign`: attacks with authentication on and off; :func:`false_alarm_runs`: fault-free
runs, whose plausibility stops are false alarms).
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterator, Sequence
from pathlib import Path

from dbc.codec import DBC_PATH
from tools.run import scenario as scenario_mod
from tools.run.processes import Part, PartFailedError, SandboxedParts, realtime_parts
from tools.safety.attacks.analysis import AttackResult, analyse
from tools.safety.attacks.attacker import ATTACKS, attacker_part


def write_configs(out: Path, auth: bool, scenario: str) -> tuple[Path, Path]:
    """The controller's TOML and a scenario with the drives' power-on authentication."""

    scen = scenario_mod.load(scenario)
    ctl = out / "controller.toml"
    ctl.write_text(
        "# attack run (docs/safety.md 5a)\n[drives]\n"
        f"require_auth = {'true' if auth else 'false'}\n"
        "[auth]\n"
        f"check_contract = {'true' if auth else 'false'}\n"
    )
    text = Path(scen.path).read_text()
    bench = (
        "\n[bench]\n"
        f'"drive.require_auth" = {"true" if auth else "false"}\n'
        f'"drive.check_contract" = {"true" if auth else "false"}\n'
    )
    if "[bench]" in text:
        raise ValueError(f"{scen.path}: attack runs add their own [bench] table")
    scen_path = out / f"{scen.path.stem}-attack.toml"
    route = f'route = "{(Path(scen.route_path)).resolve()}"'
    lines = [route if ln.strip().startswith("route") else ln for ln in text.splitlines()]
    scen_path.write_text("\n".join(lines) + bench)
    return ctl, scen_path


def wrong_dbc(out: Path, auth: bool) -> Path:
    """The project's DBC with the left wheel's Input_Vel factor doubled."""

    text = DBC_PATH.read_text()
    if auth:
        old = ' SG_ Input_Vel : 0|16@1- (0.0001,0) [-3.2767|3.2767] "rev/s" Drive_Left'
        new = ' SG_ Input_Vel : 0|16@1- (0.0002,0) [-3.2767|3.2767] "rev/s" Drive_Left'
    else:
        old = ' SG_ Input_Vel : 0|32@1- (1,0) [-20|20] "rev/s" Drive_Left'
        new = ' SG_ Input_Vel : 0|32@1- (2,0) [-20|20] "rev/s" Drive_Left'
    if old not in text:
        raise ValueError(f"{DBC_PATH}: no {old.strip()!r} to edit")
    path = out / "wrong-factor.dbc"
    path.write_text(text.replace(old, new, 1))
    return path


def run_attack(
    out: Path,
    attack: str,
    *,
    auth: bool,
    scenario: str = "fault-free",
    controller: str = "antifragile",
    at_s: float = 8.0,
    duration_s: float = 16.0,
    attempts: int = 3,
    rt_priority: int = 0,
) -> AttackResult:
    """One real-time run over udp_multicast in a private namespace with ``attack``; repeated
    (up to ``attempts`` times) while the run is invalid: the host was not tracking at the
    onset, or stopped for its drives' late feedback before the attack could be judged.

    ``rt_priority`` > 0: the controller runs on SCHED_FIFO at that priority and the bench, which
    stands in for the drives' own hardware, one above it, as ``run --rt-priority`` does."""
    for k in range(attempts):
        res = _run_once(
            out / f"try{k}",
            attack,
            auth=auth,
            scenario=scenario,
            controller=controller,
            at_s=at_s,
            duration_s=duration_s,
            rt_priority=rt_priority,
        )
        res.attempts = k + 1
        if not res.failures or not res.failures[0].startswith("invalid run"):
            break
    return res


def _run_once(
    out: Path,
    attack: str,
    *,
    auth: bool,
    scenario: str,
    controller: str,
    at_s: float,
    duration_s: float,
    rt_priority: int = 0,
) -> AttackResult:

    if attack not in (*ATTACKS, "none"):
        raise ValueError(f"unknown attack {attack!r}: choose one of {', '.join(ATTACKS)}")
    out = out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    ctl_cfg, scen = write_configs(out, auth, scenario)
    dbc = ("--dbc", str(wrong_dbc(out, auth))) if attack == "wrong-dbc" else ()
    attacker: list[Part] = []
    if attack not in ("wrong-dbc", "none"):
        attacker.append(attacker_part(out, attack, at_s, auth=auth, rt_priority=rt_priority))
    parts = realtime_parts(
        out,
        str(scen),
        duration_s,
        control=("--controller", controller, "--config", str(ctl_cfg), *dbc),
        rt_priority=rt_priority,
        others=attacker,
    )
    timeout_s = duration_s * 4 + 90
    try:
        with SandboxedParts(parts, out, timeout_s=timeout_s) as run:
            run.wait()
    except subprocess.TimeoutExpired:
        # a starved machine: a part that never started (the run is invalid, not failed)
        res = AttackResult(attack, auth)
        res.failures.append(f"invalid run: the processes did not finish in {timeout_s:g} s")
        return res
    except PartFailedError as err:
        raise RuntimeError(f"attack run failed: {err}") from err
    return analyse(out, attack, auth=auth, at_s=at_s)


def campaign(
    out: Path,
    attacks: Sequence[str],
    modes: Sequence[bool],
    *,
    scenario: str = "fault-free",
    controller: str = "antifragile",
    at_s: float = 8.0,
    duration_s: float = 16.0,
    rt_priority: int = 0,
) -> Iterator[AttackResult]:
    """Each of ``attacks`` with authentication on and off as ``modes`` says (:func:`run_attack`
    in ``out/<attack>-auth-<on|off>``): each result as its run ends."""
    for attack in attacks:
        for auth in modes:
            yield run_attack(
                out / f"{attack}-auth-{'on' if auth else 'off'}",
                attack,
                auth=auth,
                scenario=scenario,
                controller=controller,
                at_s=at_s,
                duration_s=duration_s,
                rt_priority=rt_priority,
            )


def false_alarm_runs(
    out: Path,
    n: int,
    modes: Sequence[bool],
    *,
    scenario: str = "fault-free",
    controller: str = "antifragile",
    at_s: float = 8.0,
    duration_s: float = 16.0,
    rt_priority: int = 0,
) -> Iterator[tuple[int, bool, AttackResult]]:
    """``n`` fault-free real-time runs (attack ``none``) with authentication on and off as
    ``modes`` says, in ``out/clean-<k>-auth-<on|off>``: (k, authentication, result) of each as
    its run ends."""
    for k in range(n):
        for auth in modes:
            yield (
                k,
                auth,
                run_attack(
                    out / f"clean-{k}-auth-{'on' if auth else 'off'}",
                    "none",
                    auth=auth,
                    scenario=scenario,
                    controller=controller,
                    at_s=at_s,
                    duration_s=duration_s,
                    rt_priority=rt_priority,
                ),
            )
