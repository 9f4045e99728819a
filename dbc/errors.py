"""Wire-contract errors: the DBC does not load, or a frame cannot be encoded or decoded.

They are branches of the project's one error tree (:mod:`dbc.runtime.errors`):
:class:`DbcError` is a configure-time :class:`~dbc.runtime.errors.ConfigError`,
:class:`EncodeError` / :class:`DecodeError` name the message, signal, bound and value.
"""

from __future__ import annotations

from dbc.runtime.errors import ConfigError, WheelchairError


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
