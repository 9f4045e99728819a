"""AUTOSAR SecOC-style authentication of the host's commands to the drives (docs/safety.md § 1a).

The host and each drive share a secret key (:func:`load_key`, a file the chair's config
names).  Every secured PDU the host sends a drive carries a **freshness value** (FV) and a
**truncated MAC**:

* the FV is a 64-bit counter per host->drive link, incremented for every secured PDU to that
  drive; only its low bits travel (8 in ``Set_Input_Vel_Auth``, 16 in ``Host_Auth``).  The
  receiver keeps the last FV it accepted (its *reference*) and reconstructs the full FV as the
  smallest value above the reference with the received low bits (:meth:`Verifier.verify`);
* the MAC is HMAC-SHA256 (stdlib ``hmac``) over ``frame ID (4 bytes LE) | length (1 byte) |
  authentic bytes | FV (8 bytes BE)``, truncated to its first :data:`MAC_BITS` bits (SecOC
  truncates to the most significant bits).  The authentic bytes are the setpoint frame's
  bytes 0..3 (velocity, stop reference, truncated FV) or, for a command sent with a separate
  ``Host_Auth`` PDU (SecOC's secured PDU collection), the command frame's whole payload.

A frame is accepted only if its MAC verifies at the reconstructed FV, which is then the new
reference: a replayed frame (an FV at or below the reference) cannot verify, because its MAC
was computed over its old FV.  On failure the verifier tries the FV one wrap lower, so that
a replay of one of the last 2^bits frames is counted as ``replayed`` rather than
``mac_mismatch``; both are refused.

This module only builds and checks bytes; which frames must be authenticated and what a
drive does with a refusal is :mod:`firmware_sim.drive`'s business, and when the host sends
what is :mod:`controller.node`'s.
"""

from __future__ import annotations

import hashlib
import hmac
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dbc.runtime.errors import ConfigError

#: Length of the truncated MAC on the wire.
MAC_BITS = 32
MAC_BYTES = MAC_BITS // 8
#: Truncated freshness bits in the setpoint frame and in Host_Auth.
SETPOINT_FV_BITS = 8
AUTH_FV_BITS = 16
#: The shortest key accepted (128 bits, as AES-CMAC's; HMAC-SHA256 takes up to 512).
MIN_KEY_BYTES = 16
#: A key file containing this marker is the repository's public test key.
TEST_KEY_MARKER = "TEST KEY"

#: Refusal reasons (keys of a drive's refusal counters and of the log).
REJECT_AUTH_REQUIRED = "auth_required"  # a frame that must be authenticated arrived plain
REJECT_MAC = "auth_mac_mismatch"  # no valid MAC at the expected freshness: forged or corrupt
REJECT_REPLAY = "auth_replayed"  # a valid MAC at an old freshness value: a replay
REJECT_NO_COMMAND = "auth_without_command"  # a Host_Auth with no pending command to match
REJECT_LINK = "auth_link_mismatch"  # Host_Auth names another command than the pending one
REJECT_UNAUTHENTICATED = "auth_missing"  # a command not followed by its Host_Auth
REJECT_NO_KEY = "auth_no_key"  # authentication asked of a drive that has no key


@dataclass(frozen=True)
class Key:
    """A loaded MAC key; ``is_test`` for the repository's public test key.

    The HMAC's inner and outer padded-key states (RFC 2104) are computed once, so that a MAC
    costs two SHA-256 compressions on copies of them (:func:`mac`; a test checks it against
    ``hmac.digest``).
    """

    secret: bytes
    path: str
    is_test: bool
    _inner: Any = field(init=False, repr=False, compare=False)
    _outer: Any = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        k = self.secret if len(self.secret) <= 64 else hashlib.sha256(self.secret).digest()
        k = k.ljust(64, b"\0")
        object.__setattr__(self, "_inner", hashlib.sha256(bytes(b ^ 0x36 for b in k)))
        object.__setattr__(self, "_outer", hashlib.sha256(bytes(b ^ 0x5C for b in k)))

    def __repr__(self) -> str:  # never print the secret
        return f"Key(path={self.path!r}, is_test={self.is_test})"

    def hmac_sha256(self, msg: bytes) -> bytes:
        """HMAC-SHA256 of ``msg`` under this key (== ``hmac.digest(secret, msg, "sha256")``)."""
        inner = self._inner.copy()
        inner.update(msg)
        outer = self._outer.copy()
        outer.update(inner.digest())
        return bytes(outer.digest())


def load_key(path: str | Path) -> Key:
    """Read a key file: ``#`` comment lines and one line of hex digits (>= 128 bits).

    Raises :class:`ConfigError` naming the file if it is missing, unreadable or malformed.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError as err:
        raise ConfigError(f"{p}: authentication key file not found (auth key_file)") from err
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"{p}: authentication key file unreadable: {err}") from err
    lines = [ln.strip() for ln in text.splitlines()]
    body = [ln for ln in lines if ln and not ln.startswith("#")]
    if len(body) != 1:
        raise ConfigError(
            f"{p}: an authentication key file holds exactly one line of hex digits "
            f"(found {len(body)} non-comment lines)"
        )
    try:
        secret = bytes.fromhex(body[0])
    except ValueError as err:
        raise ConfigError(f"{p}: the key is not hexadecimal: {err}") from err
    if len(secret) < MIN_KEY_BYTES:
        raise ConfigError(
            f"{p}: the key has {len(secret) * 8} bits, at least {MIN_KEY_BYTES * 8} are needed"
        )
    return Key(secret, str(p), any(TEST_KEY_MARKER in ln for ln in lines if ln.startswith("#")))


def mac(key: Key, frame_id: int, data: bytes | bytearray, fv: int) -> bytes:
    """The truncated MAC (:data:`MAC_BYTES` bytes) of ``data`` sent on ``frame_id`` at ``fv``."""
    msg = (
        frame_id.to_bytes(4, "little")
        + len(data).to_bytes(1, "little")
        + bytes(data)
        + (fv & 0xFFFF_FFFF_FFFF_FFFF).to_bytes(8, "big")
    )
    return key.hmac_sha256(msg)[:MAC_BYTES]


def mac_value(key: Key, frame_id: int, data: bytes | bytearray, fv: int) -> int:
    """:func:`mac` as the DBC's unsigned little-endian ``Auth_MAC`` signal value."""
    return int.from_bytes(mac(key, frame_id, data, fv), "little")


class Authenticator:
    """The host's side: one freshness counter per drive."""

    __slots__ = ("_fv", "key")

    def __init__(self, key: Key) -> None:
        self.key = key
        self._fv: dict[int, int] = {}

    def next_fv(self, link: int) -> int:
        """The next freshness value for drive ``link`` (1, 2, ...)."""
        fv = self._fv.get(link, 0) + 1
        self._fv[link] = fv
        return fv

    def resync(self, link: int, at_least: int) -> None:
        """Continue above ``at_least`` (a drive's reported reference after a host restart)."""
        if at_least > self._fv.get(link, 0):
            self._fv[link] = at_least

    def fv(self, link: int) -> int:
        """The latest freshness value of drive ``link`` (0: none yet)."""
        return self._fv.get(link, 0)

    def sign(self, frame_id: int, data: bytes | bytearray, fv: int) -> int:
        """The ``Auth_MAC`` signal value of ``data`` sent on ``frame_id`` at freshness ``fv``."""
        return mac_value(self.key, frame_id, data, fv)

    def mac(self, frame_id: int, data: bytes | bytearray, fv: int) -> bytes:
        """:meth:`sign` as the signal's bytes (little-endian, :data:`MAC_BYTES` of them)."""
        return mac(self.key, frame_id, data, fv)


class Verifier:
    """A drive's side: its freshness reference and the MAC check.

    The reference is not reset by a reboot (a real drive keeps it in non-volatile memory):
    frames recorded before a reboot stay replays after it.
    """

    __slots__ = ("key", "reference")

    def __init__(self, key: Key | None) -> None:
        self.key = key
        self.reference = 0

    def verify(
        self, frame_id: int, data: bytes | bytearray, fv_low: int, fv_bits: int, mac_got: int
    ) -> str:
        """Check a secured PDU; "" if authentic and fresh (the reference advances), else why not."""
        key = self.key
        if key is None:
            return REJECT_NO_KEY
        span = 1 << fv_bits
        ref = self.reference
        fv = (ref & ~(span - 1)) | (fv_low & (span - 1))
        if fv <= ref:
            fv += span
        got = mac_got.to_bytes(MAC_BYTES, "little")
        if hmac.compare_digest(mac(key, frame_id, data, fv), got):
            self.reference = fv
            return ""
        old = fv - span
        if old > 0 and hmac.compare_digest(mac(key, frame_id, data, old), got):
            return REJECT_REPLAY
        return REJECT_MAC


def linked_id(node: int, cmd: int) -> int:
    """The 11-bit ID of command ``cmd`` to ``node`` (ODrive's ``node << 5 | cmd``): what a
    ``Host_Auth`` PDU's target names."""
    return (node << 5) | cmd


def contract_digest(lines: list[str]) -> int:
    """32-bit contract hash of the canonical description of a DBC (:meth:`Codec.contract_hash`)."""
    h = hashlib.sha256("\n".join(lines).encode("utf-8")).digest()
    return int.from_bytes(h[:4], "big")
