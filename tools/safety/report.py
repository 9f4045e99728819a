"""The safety fault-injection suite as a table (``wheelchair-hil safety-report`` prints it).

Per case of :data:`tools.safety.cases.CASES` (the same ones ``tests/safety/`` runs): what
detected the fault and when, the stop time, the stop distance against
``v0 t_det + v0^2 / (2 a_stop)`` + 5 %, ``|wL - wR|`` during the stop, whether anything
resumed, and the frames rejected by reason (docs/safety.md): :func:`format_table`, as
Markdown or as plain text for a terminal; :func:`realtime_lines` for a real-time signal run
(SIGKILL, SIGSTOP then SIGCONT of the controller).
"""

from __future__ import annotations

import textwrap
from typing import Any


def _ms(v: float | None) -> str:
    return "-" if v is None else f"{v * 1000:.0f}"


def _f(v: float | None, nd: int = 2) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def _rejected(rej: dict[str, int], width: int = 0) -> str:
    text = ", ".join(f"{k} {v}" for k, v in rej.items()) or "-"
    return text if not width or len(text) <= width else text[: width - 1] + "…"


COLUMNS = (
    "case",
    "expect",
    "detected by",
    "t_det ms (limit)",
    "stop start ms",
    "HB ms",
    "stop s",
    "v0 m/s",
    "dist m (limit)",
    "|wL-wR| rad/s start/max/excess (limit); heading dev",
    "no resume",
    "frames rejected by reason",
    "result",
)
#: The plain-text table's columns (indices into a row); the rest goes on a line below each row.
TEXT_COLUMNS = (0, 1, 3, 4, 6, 7, 8, 10, 12)
TEXT_HEADERS: tuple[str, ...] = ("case", "expect", "t_det ms (lim)", "stop ms", "stop s")
TEXT_HEADERS += ("v0 m/s", "dist m (lim)", "no resume", "result")
#: The plain-text table fits a terminal this wide (rows and their detail lines).
TEXT_WIDTH = 120
#: Longest list of rejected frames shown in the plain-text table (--json has them all).
REJECTED_WIDTH = 160


def rows(results: list[Any]) -> list[list[str]]:
    out = []
    for r in results:
        det = "-" if r.detection_s is None else _ms(r.detection_s)
        if r.detection_limit_s is not None:
            det += f" ({_ms(r.detection_limit_s)})"
        dist = "-"
        if r.stop_distance_m is not None:
            dist = f"{r.stop_distance_m:.3f} ({_f(r.stop_distance_limit_m, 3)})"
        yaw = "-"
        if r.dw_max_radps is not None:
            yaw = f"{r.dw_at_detection_radps:.2f}/{r.dw_max_radps:.2f}/{r.dw_excess_radps:.3f}"
            yaw += f" ({_f(r.dw_limit_radps, 2)})" if r.dw_limit_radps is not None else " (n/a)"
            yaw += f"; {r.heading_deviation_deg:+.2f} deg"
        dev = f"; dev {r.deviation_m * 100:.1f} cm" if r.deviation_m is not None else ""
        bus = ", ".join(f"{k} {v}" for k, v in r.effects.items() if k != "injected")
        dev += f" [bus: {bus}]" if bus else ""
        out.append(
            [
                r.name,
                r.expect,
                r.detector,
                det,
                _ms(r.stop_start_s),
                _ms(r.reported_in_heartbeat_s),
                _f(r.stop_time_s),
                _f(r.v0_mps),
                dist,
                yaw,
                "-" if r.no_resume is None else ("yes" if r.no_resume else "NO"),
                _rejected(r.rejected) + dev,
                "pass" if r.passed else "FAIL",
            ]
        )
    return out


def _details(r: Any, row: list[str]) -> str:
    """What does not fit the plain-text row: detector, heartbeat, yaw, rejected frames."""
    parts = [f"detected by {row[2]}"] if row[2] != "-" else ["not detected"]
    if row[5] != "-":
        parts.append(f"in a heartbeat after {row[5]} ms")
    if row[9] != "-":
        parts.append(f"|wL-wR| start/max/excess {row[9].replace('; ', ' rad/s; heading ', 1)}")
    parts.append(f"rejected: {_rejected(r.rejected, REJECTED_WIDTH)}")
    if r.deviation_m is not None:
        parts.append(f"dev {r.deviation_m * 100:.1f} cm")
    bus = ", ".join(f"{k} {v}" for k, v in r.effects.items() if k != "injected")
    if bus:
        parts.append(f"bus: {bus}")
    return "; ".join(parts)


def format_table(results: list[Any], markdown: bool = False) -> str:
    """The suite as a table: Markdown with every column, or plain text no wider than
    :data:`TEXT_WIDTH`, one row per case and its details wrapped on the lines below it."""
    body = rows(results)
    if markdown:
        lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
        lines += ["| " + " | ".join(c.replace("|", "\\|") for c in row) + " |" for row in body]
        return "\n".join(lines)
    cols = [[row[i] for i in TEXT_COLUMNS] for row in body]
    widths = [max(len(h), *(len(r[i]) for r in cols)) for i, h in enumerate(TEXT_HEADERS)]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    lines = [fmt.format(*TEXT_HEADERS).rstrip(), fmt.format(*("-" * w for w in widths))]
    for r, row, short in zip(results, body, cols, strict=True):
        lines.append(fmt.format(*short).rstrip())
        lines += textwrap.wrap(
            _details(r, row),
            TEXT_WIDTH,
            initial_indent="    ",
            subsequent_indent="      ",
            break_on_hyphens=False,
        )
    return "\n".join(lines)


def realtime_lines(res: Any) -> list[str]:
    """A real-time signal run's figures against their limits, a line each."""
    d = res.as_dict()
    keys = (
        ("last setpoint at (sim s)", "last_setpoint_s"),
        ("v0 (m/s)", "v0_mps"),
        ("stop reference (m/s)", "stop_ref_mps"),
        ("watchdog in heartbeat after (s)", "watchdog_in_heartbeat_s"),
        ("  limit (s)", "detection_limit_s"),
        ("both wheels at standstill after (s)", "standstill_s"),
        ("  limit: watchdog + v0/a_stop + 5T (s)", "standstill_limit_s"),
        ("stop distance (m)", "stop_distance_m"),
        ("  limit (m)", "stop_distance_limit_m"),
        ("|wL-wR| at trip / max / excess (rad/s)", "dw_at_trip_radps"),
        ("heading deviation from the arc (deg)", "heading_deviation_deg"),
        ("standstill until the end (s)", "still_to_end_s"),
        ("drives idle, watchdog bit latched", "drives_idle_with_error_at_end"),
        ("controller final state", "controller_final_state"),
        ("signal reached a running controller", "signalled"),
    )
    out = [f"real time, {res.signal}, scenario {res.scenario}:"]
    for label, key in keys:
        v = d[key]
        if key == "dw_at_trip_radps":
            v = f"{d['dw_at_trip_radps']} / {d['dw_max_radps']} / {d['dw_excess_radps']}"
        elif isinstance(v, float):
            v = f"{v:.4g}"
        out.append(f"  {label:<42} {v}")
    out.append(f"  {'result':<42} {'pass' if res.passed else 'FAIL: ' + '; '.join(res.failures)}")
    return out
