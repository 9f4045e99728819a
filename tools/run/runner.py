"""The former module of the run plan and the parts, now :mod:`tools.run.plan` and
:mod:`tools.run.parts`; it re-exports :func:`~tools.run.plan.planned` only, for
tools/evaluation/task.py, which still imports it from here."""

from tools.run.plan import planned

__all__ = ["planned"]
