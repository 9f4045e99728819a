"""Arguments of ``wheelchair-hil params`` and its action: every parameter with unit, default and
bounds."""

from __future__ import annotations

import argparse
from typing import Any


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--markdown", action="store_true", help="as a Markdown table")


def main(args: argparse.Namespace, argv: list[str]) -> int:
    """Print the declared parameters of the controller's deployment file, the bench's chair
    file, a scenario's ``[scenario]`` table and every law's gains, as text or Markdown."""
    from controller.config import ControllerConfig  # lazy: the stack
    from controller.tracking import registry  # lazy
    from dbc.runtime.errors import WheelchairError  # lazy
    from dbc.runtime.params import describe  # lazy
    from firmware_sim.config import BenchConfig  # lazy
    from tools.run.scenario import ScenarioParams  # lazy

    tables: list[tuple[str, Any]] = [
        ("controller/controller.toml", ControllerConfig),
        ("firmware_sim/chair.toml", BenchConfig),
        ("<scenario>.toml [scenario]", ScenarioParams),
    ]
    for name in registry.names():
        if registry.gains_section(name) != name:  # a variant: its law's section and keys
            continue
        try:
            tables.append(
                (f"controller/gains.toml [{name}]", registry.controller_class(name).Params)
            )
        except WheelchairError as err:
            print(f"# {name}: {err}")
    for title, cls in tables:
        rows = describe(cls)
        if args.markdown:
            print(
                f"\n### {title}\n\n| key | unit | default | bounds | meaning |\n|---|---|---|---|---|"
            )
            for r in rows:
                print(
                    f"| `{r['key']}` | {r['unit']} | {r['default']} | {_bounds(r)} | {r['doc']} |"
                )
        else:
            print(f"\n{title}")
            for r in rows:
                print(
                    f"  {r['key']:<40} {r['default']!s:>12} {r['unit']:<14} {_bounds(r):<18} {r['doc']}"
                )
    return 0


def _bounds(r: dict[str, Any]) -> str:
    lo, hi = r["lo"], r["hi"]
    if lo is None and hi is None:
        return ""
    return f"[{'' if lo is None else lo}, {'' if hi is None else hi}]"
