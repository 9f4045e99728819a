"""What every set of safety figures has: the criteria it failed, its verdict, its JSON form.

The suite's case results, its real-time signal runs and the attacks
(:class:`~tools.safety.criteria.CaseResult`, :class:`~tools.safety.realtime.RealtimeResult`,
:class:`~tools.safety.attacks.analysis.AttackResult`) are dataclasses with a ``failures`` list; this
mixin gives them ``passed`` and ``as_dict``.
"""

from __future__ import annotations

import dataclasses
from typing import Any


class Verdict:
    """Mixin of a dataclass with a ``failures`` field: passed when it is empty."""

    failures: list[str]

    @property
    def passed(self) -> bool:
        return not self.failures

    def as_dict(self) -> dict[str, Any]:
        """Every field, and ``passed`` (for ``--json``)."""
        assert dataclasses.is_dataclass(self)
        d = dataclasses.asdict(self)
        d["passed"] = self.passed
        return d
