"""The Foxglove layout opens panels on topics and fields a record really has."""

from __future__ import annotations

import json
import re
from pathlib import Path

from cellguard.record.schemas import CHANNELS, CYCLE_SCHEMA, EVENT_SCHEMA
from cellguard.robot.registry import make_cell

LAYOUT = Path(__file__).parents[1] / "foxglove" / "cellguard-layout.json"


def _panels(node) -> set[str]:
    if isinstance(node, str):
        return {node}
    return _panels(node["first"]) | _panels(node["second"])


def _paths(layout: dict) -> list[str]:
    text = json.dumps(layout["configById"])
    return re.findall(r'"(?:value|topicPath|topic|topicToRender)": "(/[^"]*)"', text)


def test_every_panel_is_placed_and_configured():
    layout = json.loads(LAYOUT.read_text())
    assert _panels(layout["layout"]) == set(layout["configById"])
    kinds = {panel.split("!")[0] for panel in layout["configById"]}
    assert {"3D", "Plot", "RosOut", "StateTransitions"} <= kinds


def test_every_path_names_a_recorded_topic_and_field():
    layout = json.loads(LAYOUT.read_text())
    topics = {c.topic for c in CHANNELS}
    joints = make_cell("arm-pick-place", seed=0).profile.joint_names
    fields = {"/cycles": set(CYCLE_SCHEMA["properties"]), "/events": set(EVENT_SCHEMA["properties"])}
    for path in _paths(layout):
        topic = path if path in topics else path.rsplit(".", 1)[0]
        assert topic in topics, path
        field = path[len(topic) + 1:]
        if topic in fields:
            assert field in fields[topic], path
        if field.startswith("position["):
            assert int(field[len("position["):-1]) < len(joints), path
    labels = [p["label"] for p in layout["configById"]["Plot!joints"]["paths"]]
    assert labels == list(joints)
