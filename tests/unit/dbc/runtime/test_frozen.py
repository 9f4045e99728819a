"""dbc.runtime.frozen.fast_init: the same instances and signature as the dataclass's own
__init__, frozen the same way, and a clear refusal of what it cannot express."""

from __future__ import annotations

import dataclasses
import inspect
from dataclasses import InitVar, dataclass, field
from typing import Any

import pytest

from controller.limits import LimitedCommand
from controller.odometry import OdometryIncrement
from controller.types import Pose, ReferenceSample, StateEstimate, TrackingError, TwistCommand
from dbc.messages import SPECS
from dbc.runtime.frozen import fast_init

HOT = [Pose, ReferenceSample, StateEstimate, TwistCommand, TrackingError, OdometryIncrement]
HOT += [LimitedCommand, *(spec.cls for spec in SPECS)]


def _expected(cls: type, values: dict[str, Any]) -> Any:
    """What the dataclass's own __init__ makes: every field set by name, defaults filled in."""
    obj = object.__new__(cls)
    for f in dataclasses.fields(cls):
        object.__setattr__(obj, f.name, values.get(f.name, f.default))
    return obj


@pytest.mark.parametrize("cls", HOT, ids=lambda c: c.__qualname__)
def test_the_fast_init_makes_the_dataclasses_instance_with_its_signature(cls: type) -> None:
    fields = dataclasses.fields(cls)
    params = list(inspect.signature(cls).parameters.values())
    assert [p.name for p in params] == [f.name for f in fields]
    assert [p.default for p in params] == [
        inspect.Parameter.empty if f.default is dataclasses.MISSING else f.default for f in fields
    ]
    required = {f.name: 1000 + i for i, f in enumerate(fields) if f.default is dataclasses.MISSING}
    positional = cls(*required.values())
    assert positional == _expected(cls, required)
    everything = {f.name: 2000 + i for i, f in enumerate(fields)}
    assert cls(**everything) == _expected(cls, everything)
    assert [getattr(cls(**everything), f.name) for f in fields] == list(everything.values())
    if fields:
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(positional, fields[0].name, 0)
        with pytest.raises(TypeError):
            cls(*everything.values(), **{fields[0].name: 1})  # given twice, as before


def _refused(make: Any, why: str) -> None:
    with pytest.raises(TypeError, match=why):
        fast_init(make())


def test_what_the_fast_init_cannot_express_is_refused_by_name() -> None:
    def not_frozen() -> type:
        @dataclass(slots=True)
        class NotFrozen:
            a: float

        return NotFrozen

    def post_init() -> type:
        @dataclass(frozen=True, slots=True)
        class Checked:
            a: float

            def __post_init__(self) -> None:
                pass

        return Checked

    def factory() -> type:
        @dataclass(frozen=True, slots=True)
        class Listed:
            a: list[float] = field(default_factory=list)

        return Listed

    def initvar() -> type:
        @dataclass(frozen=True, slots=True)
        class Seeded:
            a: float
            seed: InitVar[int] = 0

        return Seeded

    def keyword() -> type:
        @dataclass(frozen=True, slots=True, kw_only=True)
        class Named:
            a: float

        return Named

    _refused(not_frozen, "NotFrozen is not a frozen dataclass with slots")
    _refused(post_init, "Checked has a __post_init__")
    _refused(factory, "Listed.a is not a plain positional field")
    _refused(initvar, "Seeded has an InitVar")
    _refused(keyword, "Named.a is not a plain positional field")
