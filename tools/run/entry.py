"""``wheelchair-hil run``'s entry: where the run happens, decided before anything heavy.

For udp_multicast outside a private network namespace, ``run`` re-executes itself inside
one (``unshare -rn``).  It does so first, having imported only the bus layer: the run
inside validates every input (scenario, route, controller, DBC) before a part starts, and
names what is wrong in one line, as a run here would.  (Importing and validating twice cost
a run 2 s of start-up on a 2-core machine.)  Otherwise :func:`tools.run.launcher.run_here`
runs here.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

from dbc.runtime import jsonsafe
from dbc.runtime.errors import BusError
from tools.bus import transport

#: Set for the run re-executed in a private namespace: why its parent chose udp_multicast.
_CHOSEN_ENV = "WHEELCHAIR_HIL_BUS_CHOSEN"


def choose_bus(interface: str | None) -> tuple[str, str]:
    """Pick the transport for ``run`` and say why: as requested, or ``chosen: ...``.

    Without ``--bus`` python-can's own configuration decides, as for ``control``
    (``CAN_INTERFACE``, can.conf); otherwise udp_multicast in a private namespace.
    """
    if interface:
        # the re-executed run inside the namespace its parent chose says the parent's reason
        chosen = os.environ.pop(_CHOSEN_ENV, "")
        if chosen and interface == "udp_multicast" and transport.in_private_namespace():
            return interface, chosen
        return interface, "as requested"
    configured = transport.python_can_config().get("interface")
    if configured:
        source = (
            f"CAN_INTERFACE={os.environ['CAN_INTERFACE']}"
            if os.environ.get("CAN_INTERFACE")
            else "python-can's can.conf"
        )
        return str(configured), f"chosen: from {source}"
    if transport.in_private_namespace():
        return "udp_multicast", "chosen: inside a private network namespace"
    ok, why = transport.sandbox_supported()
    if ok:
        return "udp_multicast", "chosen: in a new private network namespace (separate processes)"
    return (
        "virtual",
        f"chosen: one process on the virtual bus, no private namespace available ({why})",
    )


def without_live(argv: list[str]) -> list[str]:
    """``argv`` without its ``--live ADDRESS`` / ``--live=ADDRESS``."""
    out: list[str] = []
    skip = False
    for a in argv:
        if skip:
            skip = False
        elif a == "--live":
            skip = True
        elif not a.startswith("--live="):
            out.append(a)
    return out


def run(args: Any, argv: list[str]) -> int:
    """Entry of ``wheelchair-hil run`` (args from tools.cli)."""
    # nothing is written here: the run (here or inside the namespace) validates every input,
    # --out included, before it makes a directory or starts a part
    iface, why = choose_bus(args.bus)
    spec = transport.resolve(
        iface,
        args.channel,
        allow_network_multicast=args.allow_network_multicast,
        bitrate=args.bitrate,
        options=transport.bus_options_of(args.bus_option),
    )
    if (
        transport.profile(spec.interface).private_namespace
        and not spec.allow_network_multicast
        and not transport.in_private_namespace()
    ):
        if os.environ.get(transport.SANDBOX_ENV) == "1":
            raise BusError(
                "inside the sandbox but the namespace is not private; refusing udp_multicast"
            )
        rest = list(argv)
        if "--bus" not in rest:
            rest += ["--bus", "udp_multicast"]
            os.environ[_CHOSEN_ENV] = why
        print(f"bus: udp_multicast {why}", file=sys.stderr)
        if args.live is None:
            return transport.exec_in_sandbox(transport.python_argv(*rest))
        # the view serves from out here: inside the namespace nobody outside could reach it
        from tools.live.server import LiveServer, format_live_stats  # lazy: with --live only

        with LiveServer(args.live) as view:
            print(f"live: {view.url} (open it in Foxglove)", file=sys.stderr, flush=True)
            code = transport.exec_in_sandbox(
                transport.python_argv(*without_live(rest), "--live-feed", view.socket_path)
            )
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)  # the run may have refused its input
        jsonsafe.write(out / "live_stats.json", view.stats, indent=2)
        print(f"live: {format_live_stats(view.stats)}", file=sys.stderr)
        return code
    from tools.run.launcher import run_here  # lazy: the run itself, here

    return run_here(args, spec, why)
