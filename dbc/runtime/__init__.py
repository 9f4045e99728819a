"""Runtime infrastructure both sides of the bus share, which is not the wire contract: the error
tree's root, typed TOML parameters, the crash-safe MCAP writer, the forked writer process and
monotonic bus receives, and the stop signals over a part's life.  It lives under ``dbc/``
because ``dbc`` is the one package that both ``controller/`` and ``firmware_sim/`` may import
(docs/architecture.md)."""
