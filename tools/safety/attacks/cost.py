"""What authentication costs per tick: the MAC micro-benchmark of ``wheelchair-hil attack``
(``--cost`` alone), on the codec and the SecOC code the stack runs."""

from __future__ import annotations

import statistics
import time

from dbc.codec import Codec, Node, SetInputVelAuth
from dbc.secoc import MAC_BITS, SETPOINT_FV_BITS, Authenticator, Verifier, load_key
from firmware_sim.config import default_config


def auth_cost(n: int = 20000) -> dict[str, float]:
    """Median cost (us) of one tick's authentication: host side (two secured setpoints
    against two plain-encoded ones) and drive side (one setpoint's MAC check), measured on
    the codec and the SecOC code the stack runs."""

    codec = Codec.default()
    key = load_key(default_config().key_path)
    auth = Authenticator(key)
    ver = Verifier(key)
    sp = SetInputVelAuth(0.5, 0.6)
    plain: list[float] = []
    secured: list[float] = []
    verify: list[float] = []
    clock = time.perf_counter_ns
    for _ in range(n):
        t0 = clock()
        codec.encode(SetInputVelAuth(0.5, 0.6, 1, 0), Node.LEFT)
        codec.encode(SetInputVelAuth(0.5, 0.6, 1, 0), Node.RIGHT)
        t1 = clock()
        (m,) = codec.encode_secured(sp, Node.LEFT, auth)
        codec.encode_secured(sp, Node.RIGHT, auth)
        t2 = clock()
        p = codec.decode(m).payload
        t3 = clock()
        ok = ver.verify(m.arbitration_id, m.data[:4], p.freshness, SETPOINT_FV_BITS, p.mac)
        t4 = clock()
        if ok:
            raise RuntimeError(f"a genuine setpoint failed verification: {ok}")
        plain.append((t1 - t0) / 1e3)
        secured.append((t2 - t1) / 1e3)
        verify.append((t4 - t3) / 1e3)
    med = statistics.median
    return {
        "mac_bits": float(MAC_BITS),
        "host_encode_plain_us_per_tick": med(plain),
        "host_encode_secured_us_per_tick": med(secured),
        "host_auth_us_per_tick": med(secured) - med(plain),
        "drive_verify_us_per_frame": med(verify),
    }
