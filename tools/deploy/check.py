"""One line of the doctor's report (:class:`Check`) and its verdict (:class:`Status`)."""

from __future__ import annotations

import enum
from dataclasses import dataclass


class Status(enum.Enum):
    OK = "ok"
    WARN = "warning"
    FAIL = "FAIL"
    NA = "n/a"


@dataclass(frozen=True)
class Check:
    """One line of the doctor's report."""

    name: str
    status: Status
    detail: str
    fix: str = ""

    def line(self) -> str:
        text = f"{self.status.value:<8}{self.name:<12}{self.detail}"
        return f"{text} -- fix: {self.fix}" if self.fix else text
