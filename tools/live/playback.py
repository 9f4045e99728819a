"""``replay LOG --live [HOST:]PORT``: a recorded log served to Foxglove at its own pace.

Every channel of the log is advertised at once, with its schema, so that a client can
subscribe to all of them before the first message.  Playback starts when the first
client subscribes (or at once with ``wait_for_client=False``), then sends each message
when its log time is due: at the recorded pace, or ``speed`` times faster.  Messages are
sent in file order (for ``run.mcap``: log-time order; the recorder's ``/can/raw``: bus
order); a log time earlier than the previous one is sent at once.  The clients' clock
follows the log time (the server's ``time`` capability).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

from dbc.runtime.errors import WheelchairError
from tools.live.server import LiveAddress
from tools.live.view import LiveView
from tools.logs import mcap_io

log = logging.getLogger(__name__)

#: How often the clients are told the log time, in log-time ns.
_TIME_EVERY_NS = 50_000_000


def serve_log(
    path: str | Path,
    address: LiveAddress,
    *,
    speed: float = 1.0,
    wait_for_client: bool = True,
    stop_event: threading.Event | None = None,
    on_ready: Callable[[LiveView], None] | None = None,
    on_start: Callable[[], None] | None = None,
) -> Counter[str]:
    """Serve ``path``'s channels on ``address``; returns the messages sent per topic.

    ``on_ready(view)`` is called once the view listens (``view.port`` is the port),
    ``on_start()`` when playback starts.
    """
    if not (math.isfinite(speed) and speed > 0):
        raise WheelchairError(f"replay --speed {speed}: must be a positive number")
    path = Path(path)
    contents = mcap_io.read_contents(path)
    if not contents.channels:
        raise WheelchairError(f"{path}: no channels to serve")
    stop = stop_event or threading.Event()
    # a replay has no loop to protect: a client may fall further behind before it loses data
    view = LiveView(
        address.host, address.port, name=f"wheelchair-hil replay {path.name}", backlog=1 << 16
    )
    try:
        channels = {}
        for cid, ch in contents.channels.items():
            schema = contents.schemas.get(ch.schema_id)
            channels[cid] = view.channel(
                ch.topic,
                ch.message_encoding,
                schema.name if schema else "",
                schema.encoding if schema else "",
                schema.data if schema else b"",
            )
        if on_ready is not None:
            on_ready(view)
        if wait_for_client:
            log.warning("live: %s is waiting for a client (Foxglove: open %s)", path, view.url)
            while not view.subscribed():
                if stop.wait(0.05):
                    return view.counts
            stop.wait(0.5)  # the rest of the client's subscriptions
        if on_start is not None:
            on_start()
        t_wall0 = time.monotonic()
        t_log0: int | None = None
        next_time = 0
        for ch, msg in mcap_io.iter_messages(path):
            if stop.is_set():
                break
            target = channels.get(ch.id)
            if target is None:
                continue
            if t_log0 is None:
                t_log0 = msg.log_time
            delay = t_wall0 + (msg.log_time - t_log0) / 1e9 / speed - time.monotonic()
            if delay > 0 and stop.wait(delay):
                break
            if msg.log_time >= next_time:
                view.time(msg.log_time)
                next_time = msg.log_time + _TIME_EVERY_NS
            view.log(target, bytes(msg.data), msg.log_time)
        else:
            stop.wait(1.0)  # let the clients' backlogs drain before the server closes
        return view.counts
    finally:
        view.close()
