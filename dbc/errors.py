"""The project's exception tree: one root, split by phase.

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


class DbcError(ConfigError):
    """The wire contract (DBC file) is missing, malformed or inconsistent."""


class CodecError(WheelchairError):
    """A frame could not be encoded or decoded."""


class EncodeError(CodecError):
    """A value cannot be put on the wire (unknown message, missing or out-of-range signal)."""


class DecodeError(CodecError):
    """A received frame is not a valid instance of any message of the contract.

    ``reason`` is a short machine-readable tag (``unknown_id``, ``length``,
    ``range``, ``crc``, ``choice``, ``rtr``, ``malformed``) used to count
    rejected frames by cause.
    """

    def __init__(self, message: str, *, reason: str = "malformed") -> None:
        super().__init__(message)
        self.reason = reason


class BusError(WheelchairError):
    """The CAN transport could not be opened or refused an operation."""


class NamespaceError(BusError):
    """udp_multicast was requested where frames could leave the machine."""
