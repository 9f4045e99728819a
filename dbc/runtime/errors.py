"""The project's exception tree: one root, split by phase (the wire's branch is :mod:`dbc.errors`).

Configure-time problems (a DBC that does not load, a scenario key that does not
exist, a parameter out of bounds) raise :class:`ConfigError`; wire problems raise
:class:`EncodeError` / :class:`DecodeError` with the message, signal, bound and
value in the text; transport problems raise :class:`BusError`.  At tick time the
nodes catch these, count them and degrade; they never leave the loop.
"""

from __future__ import annotations


class WheelchairError(Exception):
    """Root of every error this project raises on purpose."""


class ConfigError(WheelchairError):
    """Bad configuration: a file, key, type or bound is wrong.  Raised before motion."""


class BusError(WheelchairError):
    """The CAN transport could not be opened or refused an operation."""


class NamespaceError(BusError):
    """udp_multicast was requested where frames could leave the machine."""
