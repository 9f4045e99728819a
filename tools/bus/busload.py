"""CAN 2.0 frame lengths on the wire, with worst-case bit stuffing, for bus-load figures.

A classic frame with ``n`` data bytes occupies, worst case (stuff bits inserted
after every 4 equal bits of the stuffed region, plus 3 bits of interframe space):

* 11-bit ID: ``8n + 44 + floor((34 + 8n - 1) / 4) + 3`` bits
* 29-bit ID: ``8n + 64 + floor((54 + 8n - 1) / 4) + 3`` bits

(Tindell, Burns & Wellings, "Calculating CAN message response times", 1995.)
"""

from __future__ import annotations


def frame_bits(n_data_bytes: int, extended: bool) -> int:
    n = 8 * n_data_bytes
    if extended:
        return n + 64 + (54 + n - 1) // 4 + 3
    return n + 44 + (34 + n - 1) // 4 + 3


def load_pct(bits: int, seconds: float, bitrate: int = 500_000) -> float:
    """Share of the bus (%) that ``bits`` occupy over ``seconds`` at ``bitrate``."""
    return 100.0 * bits / (seconds * bitrate) if seconds > 0 else 0.0
