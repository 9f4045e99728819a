"""The live view: a run's log channels served to Foxglove over its WebSocket protocol.

``feed`` (the writers' side: a bounded, drop-oldest queue per log writer), ``server`` (the
process that serves, as the writers see it), ``view`` (that process: foxglove-sdk's
WebSocket server), ``playback`` (a recorded MCAP served at log-time pace) and
``client`` (a minimal Foxglove WebSocket client, for tests and the benchmark).
"""
