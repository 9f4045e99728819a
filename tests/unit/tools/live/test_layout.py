"""The Foxglove layout in docs/foxglove: every topic and field it shows is in a run's log.

A layout whose panels name a topic or a field the log does not have shows an empty panel
and no error, so this test walks each panel's paths through the schema of its channel in
the MCAP of a short run (the live view serves the same channels).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

from tools.cli import main as cli_main
from tools.logs import mcap_io

LAYOUT = Path(__file__).resolve().parents[4] / "docs" / "foxglove" / "wheelchair-hil-layout.json"


@pytest.fixture(scope="module")
def schemas(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, Any]]:
    out = tmp_path_factory.mktemp("layout-run")
    args = ["run", "--bus", "virtual", "--scenario", "short", "--duration", "1"]
    assert cli_main([*args, "--controller", "baseline", "--out", str(out)]) == 0
    contents = mcap_io.read_contents(out / "run.mcap")
    return {
        ch.topic: json.loads(contents.schemas[ch.schema_id].data)
        for ch in contents.channels.values()
    }


def _panel_paths(layout: dict[str, Any]) -> list[tuple[str, str]]:
    """``(panel id, topic or message path)`` of every panel of the layout."""
    out: list[tuple[str, str]] = []
    for pid, cfg in layout["configById"].items():
        out += [(pid, t) for t in (cfg.get("topics") or {})]
        out += [(pid, p["value"]) for p in cfg.get("paths") or []]
        out += [(pid, cfg[k]) for k in ("topicToRender", "topicPath") if cfg.get(k)]
    return out


def _split(path: str, topics: set[str]) -> tuple[str, list[str]]:
    """A message path's topic (the longest one that prefixes it) and its field names."""
    topic = max((t for t in topics if path == t or path.startswith(t + ".")), key=len, default="")
    rest = re.sub(r"\[[^\]]*\]|\{[^}]*\}", "", path[len(topic) :])  # slices and filters
    return topic, [f for f in rest.split(".") if f]


def _field(schema: dict[str, Any], names: list[str]) -> dict[str, Any] | None:
    for name in names:
        if schema.get("type") == "array":
            schema = schema.get("items") or {}
        prop = (schema.get("properties") or {}).get(name)
        if prop is None:
            return None
        schema = prop
    return schema


def test_every_panel_of_the_layout_names_a_topic_and_field_the_log_has(
    schemas: dict[str, dict[str, Any]],
) -> None:
    layout = json.loads(LAYOUT.read_text())
    paths = _panel_paths(layout)
    assert len(paths) >= 15
    missing = []
    for pid, path in paths:
        topic, fields = _split(path, set(schemas))
        field = _field(schemas[topic], fields) if topic else None
        if field is None:
            missing.append((pid, path))
        elif fields:
            assert field.get("type") in ("number", "integer"), (pid, path, field)  # plotted
    assert not missing


def test_every_panel_of_the_layout_is_placed() -> None:
    layout = json.loads(LAYOUT.read_text())

    def leaves(node: Any) -> list[str]:
        if isinstance(node, str):
            return [node]
        return leaves(node["first"]) + leaves(node["second"])

    placed = leaves(layout["layout"])
    assert sorted(placed) == sorted(layout["configById"])
    assert {p.split("!")[0] for p in placed} == {"3D", "Plot", "Log", "RawMessages"}
