"""A recorded log served to Foxglove at the recorded pace, or K times faster (``replay --live``),
its frames re-transmitted on a bus at the same time if one is given.  The view itself is
:func:`tools.live.playback.serve_log` (the ``[live]`` extra, imported when it serves)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import can

from tools.live.address import LiveAddress
from tools.replay.retransmit import retransmit

if TYPE_CHECKING:
    from tools.live.view import LiveView


def serve(
    path: Path,
    address: LiveAddress,
    *,
    speed: float = 1.0,
    wait_for_client: bool = True,
    stop_event: threading.Event | None = None,
    bus: can.BusABC | None = None,
    on_ready: Callable[[LiveView], None] | None = None,
) -> tuple[dict[str, int], int | None]:
    """Serve ``path`` on ``address`` from when the first client subscribes (or at once);
    with ``bus``, re-transmit its frames from the same moment.  Returns the messages served
    per channel and the frames re-transmitted (None without a bus)."""
    from tools.live.playback import serve_log  # lazy: the [live] extra, with --live only

    sender: threading.Thread | None = None
    sent: list[int] = []

    def started() -> None:
        nonlocal sender
        if bus is not None:
            sender = threading.Thread(
                target=lambda: sent.append(
                    retransmit(path, bus, speed=speed, stop_event=stop_event)
                ),
                name="retransmit",
                daemon=True,
            )
            sender.start()

    counts = serve_log(
        path,
        address,
        speed=speed,
        wait_for_client=wait_for_client,
        stop_event=stop_event,
        on_ready=on_ready,
        on_start=started,
    )
    if sender is not None:
        sender.join()
    return counts, (sent[0] if sent else None)
