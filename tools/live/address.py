"""``--live [HOST:]PORT``: where the live view listens (parsed here, for the CLI and the room)."""

from __future__ import annotations

from dataclasses import dataclass

#: The live view binds this unless a host is given: nobody off the machine sees a run.
DEFAULT_HOST = "127.0.0.1"


@dataclass(frozen=True)
class LiveAddress:
    """Where the live view listens (``--live [HOST:]PORT``)."""

    host: str = DEFAULT_HOST
    port: int = 8765

    @classmethod
    def parse(cls, text: str) -> LiveAddress:
        """``PORT``, ``HOST:PORT`` or ``[IPv6]:PORT``; the error names the text and the rule."""
        host, sep, port_text = text.rpartition(":")
        if not sep:
            host, port_text = DEFAULT_HOST, text
        host = host.strip("[]") or DEFAULT_HOST
        try:
            port = int(port_text)
        except ValueError:
            raise ValueError(f"--live {text!r}: PORT must be an integer 0..65535") from None
        if not 0 <= port <= 65535:
            raise ValueError(f"--live {text!r}: PORT {port} is outside 0..65535")
        return cls(host, port)

    def __str__(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"
