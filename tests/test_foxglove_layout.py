"""config/foxglove-layout.json is what tests/foxglove_layout.py builds, and it plots only
fields the log's schemas declare (a renamed field would leave a panel silently empty)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

pytest.importorskip("foxglove.layouts")

from foxglove_layout import layout_json  # noqa: E402

from furnace_model.log.schema import LOG, topics  # noqa: E402
from furnace_model.simulation.furnace import PAPER  # noqa: E402

TOPICS = topics(PAPER)
"""The paper's furnace's topics, which these tests check."""

LAYOUT = Path(__file__).resolve().parents[1] / "config" / "foxglove-layout.json"


def _panels(node: dict) -> list[dict]:
    content = node.get("content", node)
    if content.get("type") == "panel":
        return [content]
    return [p for item in content.get("items", []) for p in _panels(item)]


def _declared(path: str) -> bool:
    topic = next((t for t in sorted(TOPICS, key=len, reverse=True) if path.startswith(t)), None)
    if topic is None:
        return False
    rest = re.sub(r"^\{[^}]*\}", "", path[len(topic):])  # a message filter {field=="value"}
    schema = TOPICS[topic].schema
    for name in rest.lstrip(".").split("."):
        schema = schema.get("properties", {}).get(name)
        if schema is None:
            return False
    return "type" in schema


def test_the_committed_layout_is_the_generated_one() -> None:
    assert LAYOUT.read_text(encoding="utf-8") == layout_json(), \
        "regenerate: python tests/foxglove_layout.py > config/foxglove-layout.json"


def test_every_plotted_path_is_a_declared_field() -> None:
    panels = _panels(json.loads(LAYOUT.read_text(encoding="utf-8")))
    paths = [s["value"] for p in panels if p["panelType"] == "Plot"
             for s in p["config"]["paths"]]
    assert len(paths) >= 6 + 3 + 6
    assert [p for p in paths if not _declared(p)] == []
    assert not _declared("/furnace/thermocouples.soak_9")  # the check can fail
    logs = [p for p in panels if p["panelType"] == "Log"]
    assert [p["config"]["topicToRender"] for p in logs] == [LOG]
