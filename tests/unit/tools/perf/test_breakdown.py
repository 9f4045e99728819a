"""``bench --case breakdown``: a lock-step step split by component, the timers removed after."""

from __future__ import annotations

from controller.diagnosis import FaultBank
from controller.tracking import registry
from tools.perf.breakdown import COMPONENTS, breakdown, format_breakdown


def test_a_step_splits_into_its_components_and_the_classes_are_left_untimed() -> None:
    law = registry.controller_class("baseline")
    before = (FaultBank.predict, law.step)
    r = breakdown("baseline", "short")
    assert (FaultBank.predict, law.step) == before  # the timers are gone
    rows = {(row["side"], row["component"]): row["us_per_step"] for row in r["components"]}
    for key in [
        ("host", "law"),
        ("host", "fault bank"),
        ("host", "EKF"),
        ("host", "encode and MAC"),
        ("host", "reference"),
        ("bench", "physics and drive loops"),
        ("bench", "drives' frames"),
        ("bench", "decode"),
    ]:
        assert rows.get(key, 0.0) > 0.0, (key, rows)
    # own times: none negative, and together they are the timed loop
    assert min(rows.values()) >= 0.0, rows
    assert abs(sum(rows.values()) - r["step_us_timed_loop"]) < 1e-6
    # every component named in the table is one the docs list
    named = {c for c, *_ in COMPONENTS} | {"law", "physics and drive loops"}
    assert {c for _, c in rows} <= named
    table = format_breakdown([r])
    assert "| host | fault bank |" in table and "baseline (us/step)" in table
