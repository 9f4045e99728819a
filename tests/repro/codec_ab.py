"""The codec of a git revision against the working tree's, in one process.

    python -m tests.repro.codec_ab [REV] [--calls N] [--rounds R]

``dbc/codec.py`` at ``REV`` (default ``HEAD``) is loaded beside the working tree's (both on
the working tree's ``dbc.bitpack`` and DBC).  First the two must agree: for every message of
the contract, a sample payload encodes to the same ID and bytes under both, and those bytes
decode to the same fields.  Then ``wheelchair-hil bench``'s three codec rows
(``Get_Encoder_Estimates``, ``Set_Input_Vel_Auth``, ``Bench_Truth_Pose``): encode and decode
of one frame, µs per call, the median (and the least) over ``R`` rounds of ``N`` calls, the two codecs
interleaved round by round (which one goes first alternates), so that both see the same
machine.  Wall-clock figures: indicative only on a shared machine.
"""

from __future__ import annotations

import argparse
import dataclasses
import enum
import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
import typing
from pathlib import Path
from types import ModuleType
from typing import Any

from dbc import codec as current

ROOT = Path(__file__).resolve().parents[2]
#: ``wheelchair-hil bench``'s codec rows: (DBC message, payload class, its fields, node).
ROWS: tuple[tuple[str, str, tuple[Any, ...], str | None], ...] = (
    ("Get_Encoder_Estimates", "EncoderEstimates", (12.5, -0.75), "LEFT"),
    ("Set_Input_Vel_Auth", "SetInputVelAuth", (1.25, 1.5, 3, 0xDEADBEEF), "LEFT"),
    ("Bench_Truth_Pose", "TruthPose", (12.345, -6.789, 1.2345), None),
)


def load_at(rev: str) -> ModuleType:
    """``dbc/codec.py`` as it is at ``rev``, imported as a module of its own."""
    text = subprocess.run(
        ["git", "show", f"{rev}:dbc/codec.py"], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout
    path = Path(tempfile.mkdtemp(prefix="codec-ab-")) / "codec_at_rev.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("codec_at_rev", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up while the class is made
    spec.loader.exec_module(mod)
    return mod


def _sample(lo: float, hi: float, typ: Any, i: int) -> Any:
    if isinstance(typ, type) and issubclass(typ, enum.IntEnum):
        members = [m for m in typ if lo <= int(m) <= hi]
        return members[i % len(members)]
    if typ is bool:
        return bool(i % 2)
    a, b = max(lo, -1000.0), min(hi, 1000.0)
    return int(a + (b - a) * 0.37) if typ is int else a + (b - a) * 0.37


def _fields(payload: Any) -> dict[str, Any]:
    return {
        f.name: (int(v) if isinstance(v := getattr(payload, f.name), enum.Enum) else v)
        for f in dataclasses.fields(payload)
    }


def check_identical(mod: ModuleType, a: Any, b: Any) -> int:
    """Every message: the same frame from both codecs, and the same fields back; the count."""
    n = 0
    for cls_b, node_b, name in b.all_messages():
        bound = b._bound(cls_b, node_b)
        hints = typing.get_type_hints(cls_b)
        values = {
            f: _sample(lo, hi, hints[f], i) for i, (f, _s, lo, hi, _u) in enumerate(bound.limits)
        }
        cls_a = getattr(mod, cls_b.__name__)
        node_a = None if node_b is None else mod.Node(int(node_b))
        hints_a = typing.get_type_hints(cls_a)
        values_a = {
            f: (hints_a[f](int(v)) if isinstance(v, enum.Enum) else v) for f, v in values.items()
        }
        ma, mb = a.encode(cls_a(**values_a), node_a), b.encode(cls_b(**values), node_b)
        same = (ma.arbitration_id, ma.is_extended_id, bytes(ma.data)) == (
            mb.arbitration_id,
            mb.is_extended_id,
            bytes(mb.data),
        )
        if not same:
            raise SystemExit(f"{name}: {ma} != {mb}")
        fa, fb = a.decode(mb), b.decode(ma)
        if _fields(fa.payload) != _fields(fb.payload) or type(fb.payload) is not cls_b:
            raise SystemExit(f"{name}: decoded {fa.payload} != {fb.payload}")
        n += 1
    return n


def _per_call_us(fn: Any, calls: int) -> float:
    t0 = time.perf_counter_ns()
    for _ in range(calls):
        fn()
    return (time.perf_counter_ns() - t0) / calls / 1000.0


def main() -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.repro.codec_ab", description=__doc__)
    ap.add_argument("rev", nargs="?", default="HEAD")
    ap.add_argument("--calls", type=int, default=20000)
    ap.add_argument("--rounds", type=int, default=15)
    args = ap.parse_args()
    mod = load_at(args.rev)
    dbc = current.DBC_PATH
    codecs = {args.rev: mod.Codec(dbc), "working tree": current.Codec(dbc)}
    print(f"identical frames and fields: {check_identical(mod, *codecs.values())} messages")
    cases: dict[tuple[str, str, str], Any] = {}
    for name, cls_name, values, node_name in ROWS:
        for label, (m, codec) in zip(
            codecs, ((mod, codecs[args.rev]), (current, codecs["working tree"])), strict=True
        ):
            payload = getattr(m, cls_name)(*values)
            node = None if node_name is None else m.Node[node_name]
            msg = codec.encode(payload, node)
            cases[(name, "encode", label)] = lambda c=codec, p=payload, n=node: c.encode(p, n)
            cases[(name, "decode", label)] = lambda c=codec, msg=msg: c.decode(msg)
    times: dict[tuple[str, str, str], list[float]] = {k: [] for k in cases}
    labels = list(codecs)
    for r in range(args.rounds):
        for name, _c, _v, _n in ROWS:
            for op in ("encode", "decode"):
                for label in labels if r % 2 == 0 else labels[::-1]:
                    times[(name, op, label)].append(
                        _per_call_us(cases[(name, op, label)], args.calls)
                    )
    print(
        f"µs per frame, median of {args.rounds} interleaved rounds of {args.calls} calls "
        f"(indicative): {labels[0]} -> {labels[1]}"
    )
    for name, _c, _v, _n in ROWS:
        cells = []
        for op in ("encode", "decode"):
            a, b = (times[(name, op, label)] for label in labels)
            cells.append(
                f"{op} {statistics.median(a):.2f} -> {statistics.median(b):.2f} "
                f"(min {min(a):.2f} -> {min(b):.2f})"
            )
        print(f"  {name:24s} {'; '.join(cells)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
