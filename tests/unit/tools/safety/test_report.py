"""The safety table: every figure of a case, in a terminal no wider than 120 columns."""

from __future__ import annotations

from tools.safety import report
from tools.safety.cases import CASES
from tools.safety.criteria import CaseResult


def _wide_case(name: str) -> CaseResult:
    return CaseResult(
        name=name,
        fault="encoder-stuck",
        expect="safe-stop",
        detector_expected="host",
        detector="host: ENCODER_JUMP/STUCK (brake) after a very long explanation of why",
        detection_s=0.1234,
        detection_limit_s=0.25,
        stop_start_s=0.1301,
        stop_time_s=1.234,
        v0_mps=1.1,
        stop_distance_m=0.987,
        stop_distance_limit_m=1.234,
        dw_at_detection_radps=0.12,
        dw_max_radps=0.34,
        dw_excess_radps=0.005,
        dw_limit_radps=0.5,
        heading_deviation_deg=-0.42,
        reported_in_heartbeat_s=0.2,
        no_resume=True,
        deviation_m=0.012,
        rejected={f"reason_{k}": 1000 + k for k in range(30)},
        effects={"injected": 1, "dropped": 77, "delayed": 12},
        failures=["stop distance 0.99 m above 0.95 m"],
    )


def test_the_plain_table_fits_120_columns_and_keeps_every_figure() -> None:
    longest = max((c.name for c in CASES), key=len)
    results = [_wide_case(longest), _wide_case("short")]
    text = report.format_table(results)
    widths = [len(line) for line in text.splitlines()]
    assert max(widths) <= report.TEXT_WIDTH, max(widths)
    for figure in (longest, "123 (250)", "130", "1.23", "0.987 (1.234)", "yes", "FAIL"):
        assert figure in text
    flat = " ".join(text.split())
    assert "detected by host: ENCODER_JUMP/STUCK (brake)" in flat
    assert "in a heartbeat after 200 ms" in flat
    assert "0.12/0.34/0.005 (0.50)" in flat and "-0.42 deg" in flat
    assert "reason_0 1000" in flat and "dev 1.2 cm" in flat and "dropped 77" in flat


def test_the_markdown_table_keeps_one_row_per_case_with_every_column() -> None:
    text = report.format_table([_wide_case("a"), _wide_case("b")], markdown=True)
    lines = text.splitlines()
    assert len(lines) == 4
    assert all(ln.count(" | ") >= len(report.COLUMNS) - 1 for ln in lines[2:])
