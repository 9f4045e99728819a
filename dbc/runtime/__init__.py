"""Runtime infrastructure both sides of the bus share, which is not the wire contract: the error
tree's root, typed TOML parameters, the crash-safe MCAP writer, the forked writer process,
monotonic bus receives, the stop signals over a part's life and real-time scheduling.  It
lives under ``dbc/`` because ``dbc`` is the one package that both ``controller/`` and
``firmware_sim/`` may import (docs/architecture.md)."""
