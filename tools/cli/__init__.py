"""``wheelchair-hil``: the project's command line.

:data:`COMMANDS` maps each subcommand to its help line, its module here
(``tools/cli/<command>.py``) and the ``module:function`` that runs it.  A command's module
holds its parser (``add_arguments``) and beside it its action (``main(args, argv)``: the
argument handling, the printing and the exit status), which calls the library functions of
the domain modules (tools/run, tools/replay, ...), imported inside the action where they
would bring numpy, scipy or python-can.  Only the invoked command's modules are imported, so
``--help`` stays fast and a missing optional dependency breaks one subcommand with a clear
message, not the whole program.  The chair's install (``control``, ``doctor``,
``install-service``, ``record``) needs no extra; a command that needs one declares it
(:attr:`Command.extras`) and, where it is not installed, says which to install in one line
before its modules are imported (``evaluate needs the optional extra [eval] (matplotlib,
tqdm not installed): pip install 'wheelchair-hil[eval]'``).  Errors the project raises on
purpose (bad scenario, unknown controller, unreachable bus ...) are printed as one line
naming the file, key or limit, with exit status 2.  Output cut short by its reader
(``wheelchair-hil params | head``) ends quietly with status 141, as a shell tool killed by
SIGPIPE would.

``--scenario-dir DIR`` (before or after the subcommand) searches DIR for scenario names
before the packaged scenarios; it sets ``WHEELCHAIR_HIL_SCENARIOS`` for the processes the
command starts.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import logging
import os
import re
import sys
import textwrap
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from dbc.runtime import stopping
from dbc.runtime.errors import WheelchairError
from tools import extras

log = logging.getLogger("wheelchair-hil")

Entry = Callable[[argparse.Namespace, list[str]], int]


@dataclass(frozen=True)
class Command:
    """One subcommand: its help line, its module and its entry point."""

    help: str
    arguments: str  # module with ``add_arguments(parser)``
    entry: str  # "module:function", called as ``function(args, argv) -> exit status``
    #: the optional extras (pyproject.toml) its modules import beyond the chair's install
    extras: tuple[str, ...] = ()


COMMANDS: dict[str, Command] = {
    "run": Command(
        "bench + controller + recorder on one bus, then summary.json",
        "tools.cli.run",
        "tools.cli.run:main",
    ),
    "sim": Command(
        "the bench alone (drives, physics, localizer) for a controller elsewhere",
        "tools.cli.sim",
        "tools.cli.sim:main",
    ),
    "control": Command(
        "the controller alone, for the bench or a real chair's drives",
        "tools.cli.control",
        "tools.cli.control:main",
    ),
    "record": Command(
        "record every frame on the bus to MCAP", "tools.cli.record", "tools.cli.record:main"
    ),
    "sandbox": Command(
        "run CMD in a private network namespace prepared for udp_multicast",
        "tools.cli.sandbox",
        "tools.cli.sandbox:main",
    ),
    "params": Command(
        "list every parameter with unit, default and bounds",
        "tools.cli.params",
        "tools.cli.params:main",
    ),
    "replay": Command(
        "re-transmit a recorded MCAP, verify a controller against it, or ask what-if",
        "tools.cli.replay",
        "tools.cli.replay:main",
    ),
    "summarize": Command(
        "recompute summary.json from a run's MCAP alone",
        "tools.cli.summarize",
        "tools.cli.summarize:main",
    ),
    "inject": Command(
        "inject or clear a fault in a running bench (Bench_Fault_Command)",
        "tools.cli.inject",
        "tools.cli.inject:main",
    ),
    "bench": Command(
        "benchmark suite: step times, cvxpy ratio, real-time factor, lateness, latency, "
        "bus load, memory",
        "tools.cli.bench",
        "tools.cli.bench:main",
    ),
    "evaluate": Command(
        "the paper's experiments as a campaign: results.json, report.md, figures, logs",
        "tools.cli.evaluate",
        "tools.cli.evaluate:main",
        extras=("eval",),
    ),
    "tune": Command(
        "tune a controller's gains: one optimiser, objective and budget for all, on "
        "scenarios disjoint from the evaluation's; writes scenarios/tuning/gains.toml",
        "tools.cli.tune",
        "tools.cli.tune:main",
    ),
    "attack": Command(
        "the bus attacks on real-time runs across processes, with and without authentication, "
        "and the authentication's cost per tick",
        "tools.cli.attack",
        "tools.cli.attack:main",
    ),
    "soak": Command(
        "real-time reliability over long runs: routes back to back with every fault kind, a "
        "rogue node and process kills at seeded random moments, judged from the logs",
        "tools.cli.soak",
        "tools.cli.soak:main",
    ),
    "doctor": Command(
        "pre-flight check of a chair before the controller may arm (moves no wheel)",
        "tools.cli.doctor",
        "tools.cli.doctor:main",
    ),
    "install-service": Command(
        "write the systemd unit that runs the controller on a chair (the doctor first)",
        "tools.cli.install_service",
        "tools.cli.install_service:main",
    ),
    "safety-report": Command(
        "run the safety fault-injection suite and print every case against its criteria",
        "tools.cli.safety_report",
        "tools.cli.safety_report:main",
    ),
}

#: The parts of a run: logged at INFO and profiled under WHEELCHAIR_HIL_PROFILE.
PARTS = ("sim", "control", "record")
#: Commands whose loops end on a stop signal (dbc.runtime.stopping.STOP) and then exit with
#: their own status; any other command is interrupted by it (exit 128 + signal).
POLLS_STOP = (*PARTS, "run", "replay", "soak")
#: Exit status when stdout's reader went away (128 + SIGPIPE, what a shell reports).
EXIT_BROKEN_PIPE = 141
DIST = "wheelchair-hil"
_SCENARIO_DIR_HELP = (
    "look up scenario and route names in DIR before the packaged scenarios (sets "
    "WHEELCHAIR_HIL_SCENARIOS for the processes started)"
)


def version() -> str:
    """The installed distribution's version (the checkout's, in an editable install)."""
    import importlib.metadata  # lazy: 50 ms before the stop signals' handlers are in place

    try:
        return importlib.metadata.version(DIST)
    except importlib.metadata.PackageNotFoundError:
        return "unknown (not installed)"


def plain(doc: str | None) -> str | None:
    """A docstring as help text: reST's ````literal```` and ``:role:`target``` as plain text."""
    if doc is None:
        return None
    doc = re.sub(r":[a-z]+:`~?([^`]+)`", r"\1", doc)
    return re.sub(r"``([^`]+)``", r"\1", doc)


def _selected(argv: Sequence[str]) -> str | None:
    """The subcommand named on the command line (the first argument that is one)."""
    return next((a for a in argv if a in COMMANDS), None)


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The parser; only the invoked command's arguments are declared (all when ``argv`` is None).

    A command whose arguments module cannot be imported (a missing optional dependency)
    is still listed, and says why when it is invoked.
    """
    ap = argparse.ArgumentParser(
        prog="wheelchair-hil",
        description="Antifragile wheelchair trajectory tracking over CAN: controller, bench, logs, evaluation.",
    )
    ap.add_argument(
        "-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)"
    )
    ap.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    ap.add_argument("--scenario-dir", metavar="DIR", default=None, help=_SCENARIO_DIR_HELP)
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")
    chosen = None if argv is None else _selected(argv)
    for name, cmd in COMMANDS.items():
        if argv is not None and name != chosen:
            sub.add_parser(name, help=cmd.help)
            continue
        try:
            module = importlib.import_module(cmd.arguments)
        except ImportError as err:
            sub.add_parser(name, help=f"unavailable: {_unavailable(cmd, err)}")
            continue
        p = sub.add_parser(
            name,
            help=cmd.help,
            description=_description(cmd.help, module.__doc__),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        module.add_arguments(p)
        # also after the subcommand; SUPPRESS keeps a value given before it
        p.add_argument(
            "--scenario-dir", metavar="DIR", default=argparse.SUPPRESS, help=_SCENARIO_DIR_HELP
        )
    return ap


def _description(summary: str, doc: str | None) -> str:
    """A command's ``--help`` text: what it does (its one-line summary), then its arguments
    module's docstring less its first paragraph where that only titles the module
    ("Arguments of ...")."""
    text = (plain(doc) or "").strip("\n")
    first, _, rest = text.partition("\n\n")
    if first.startswith("Arguments of"):
        text = rest.strip("\n")
    head = textwrap.fill(summary[:1].upper() + summary[1:] + ".", width=80)
    return f"{head}\n\n{text}" if text else head


def entry_point(name: str) -> Entry:
    """The function that runs ``name``, imported now (WheelchairError if it cannot be)."""
    module_name, func = COMMANDS[name].entry.split(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise WheelchairError(
            f"{name} is unavailable: {_unavailable(COMMANDS[name], err)}"
        ) from err
    run: Entry = getattr(module, func)
    return run


def _unavailable(cmd: Command, err: ImportError) -> str:
    """Why a command's module did not import, and the extras that would bring it."""
    return f"{err} ({extras.hint(cmd.extras)})" if cmd.extras else str(err)


def _profiled(run: Entry, args: argparse.Namespace, argv: list[str], out_dir: Path) -> int:
    """Run one part under cProfile (WHEELCHAIR_HIL_PROFILE=DIR) and dump DIR/<part>.prof."""
    import cProfile  # lazy: only when profiling

    out_dir.mkdir(parents=True, exist_ok=True)
    prof = cProfile.Profile()
    try:
        return int(prof.runcall(run, args, argv))
    finally:
        prof.dump_stats(out_dir / f"{args.command}.prof")


def entry() -> None:
    """The program (``wheelchair-hil``, ``python -m tools.cli``): one command, then exit with
    its status.  SIGTERM and SIGINT ask it to stop from its first line to the interpreter's
    last instant (:mod:`dbc.runtime.stopping`): they never kill it."""
    stopping.install()
    stopping.at("start")
    try:
        status = _guarded(None)
    finally:
        stopping.seal()
    sys.exit(status)


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command in this process and return its exit status (tests and scripts: the
    process's own signal handlers are back afterwards)."""
    with stopping.handled():
        return _guarded(argv)


def _guarded(argv: Sequence[str] | None) -> int:
    try:
        return _main(argv)
    except stopping.StopRequested as stop:  # while an error was being reported
        return 128 + stop.signum


def _main(argv: Sequence[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    chosen = _selected(argv)
    if chosen is not None:
        try:  # before its arguments' module is imported: that may need the extra too
            extras.require(chosen, *COMMANDS[chosen].extras)
        except extras.MissingExtraError as err:
            print(f"wheelchair-hil: error: {err}", file=sys.stderr)
            return 2
    args = build_parser(argv).parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    if args.command in PARTS:
        level = min(level, logging.INFO)
    logging.basicConfig(
        level=level, format="%(asctime)s %(name)s %(levelname)s: %(message)s", stream=sys.stderr
    )
    try:
        if args.command not in POLLS_STOP:
            stopping.raise_on_stop()
        if args.scenario_dir is not None:
            _use_scenario_dir(args.scenario_dir)
        run = entry_point(args.command)
        profile_dir = os.environ.get("WHEELCHAIR_HIL_PROFILE")
        if profile_dir and args.command in PARTS:
            return _profiled(run, args, argv, Path(profile_dir))
        try:
            status = run(args, argv)
        except ImportError as err:  # an action's own (lazy) import of an extra's module
            cmd = COMMANDS[args.command]
            if not cmd.extras:
                raise
            raise WheelchairError(
                f"{args.command} is unavailable: {_unavailable(cmd, err)}"
            ) from err
        sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
        return status
    except BrokenPipeError:
        return _stdout_gone()
    except WheelchairError as err:
        print(f"wheelchair-hil: error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        # a fault of the machine (disk full, read-only, a file where a directory must be):
        # one line with the path and the OS's reason, not a traceback
        print(f"wheelchair-hil: error: {os_reason(err)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    except stopping.StopRequested as stop:
        print(f"wheelchair-hil: stopped by {stop}", file=sys.stderr)
        return 128 + stop.signum


def _use_scenario_dir(path: str) -> None:
    if not Path(path).expanduser().is_dir():
        raise WheelchairError(f"--scenario-dir {path}: not a directory")
    os.environ["WHEELCHAIR_HIL_SCENARIOS"] = str(Path(path).expanduser().resolve())


def _stdout_gone() -> int:
    """stdout's reader closed it: no traceback, and nothing more written to it at exit."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return EXIT_BROKEN_PIPE


def os_reason(err: OSError) -> str:
    """``PATH: ENOSPC (No space left on device)`` for an OS error (the path if it has one)."""
    name = errno.errorcode.get(err.errno or 0, "") if err.errno else ""
    where = " -> ".join(str(p) for p in (err.filename, err.filename2) if p is not None)
    why = f"{name} ({err.strerror})" if name else (err.strerror or str(err))
    return f"{where}: {why}" if where else why


if __name__ == "__main__":
    entry()
