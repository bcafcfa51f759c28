"""The JSON channels' schemas load in Foxglove Studio and Lichtblick, and every message the writer writes fits them.

Foxglove's JSON-schema parser (mcap-support's parseJsonSchema) turns each schema into message datatypes: it needs
``"type": "object"`` and ``properties`` on every object and one type per field, and throws on anything else (a list
of types such as ``["integer", "null"]``, an ``enum`` without a type, an object with only
``additionalProperties``): all four JSON channels failed it. An optional field is left out when absent; records
written before, with null there, read the same.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from mcap.reader import make_reader
from record_synth import DT_NS, JOINTS, context, rewrite, tick

from cellguard.control.events import Event
from cellguard.record.reader import open_record
from cellguard.record.schemas import BY_TOPIC, CHANNELS
from cellguard.record.writer import Recorder

SCALARS = ("boolean", "string", "number", "integer")
OPTIONAL = ("cycle", "joint", "asked", "sent", "category")


def foxglove_problems(schema: dict, name: str) -> list[str]:
    """What Foxglove's parser would throw on, by its rule: an object with properties, each of one scalar, object or
    array type, an array's items one scalar or object type."""
    if schema.get("type") != "object" or not isinstance(schema.get("properties"), dict):
        return [f"{name}: not an object with properties"]
    problems = []
    for field, spec in schema["properties"].items():
        kind, path = spec.get("type"), f"{name}.{field}"
        items = spec.get("items", {}).get("type") if kind == "array" else None
        if kind == "object" or items == "object":
            problems += foxglove_problems(spec if kind == "object" else spec["items"], path)
        elif kind not in SCALARS and items not in SCALARS:
            problems.append(f"{path}: type {kind!r}")
    return problems


def _record(folder: Path) -> Path:
    """Events with every optional field absent or present, a NaN reading, and a cycle's features with a NaN."""
    rec = Recorder.create(folder, joints=JOINTS, dt_ns=DT_NS, context=context(), epoch_wall_ns=1_790_000_000 * 10**9)
    rec.event(Event(0, "record_start", "before the first cycle"))  # no cycle, joint, readings or category
    rec.cycle_begin(0, "acceptance", 0)
    for k in range(200):
        tick(rec, k, 0)
    rec.event(Event(100 * DT_NS, "position_clamp", "clamped", joint="elbow", asked=math.nan, sent=0.5), 0)
    rec.event(Event(150 * DT_NS, "protective_stop", "stop", category=1), 0)
    rec.measurements(150 * DT_NS, 0, {"camera": [0.1, 0.2, 0.3]})
    rec.cycle_end({"cycle": 0, "phase": "acceptance", "success": True, "features": {"a": 1.0, "b": math.nan}},
                  200 * DT_NS)
    rec.close()
    return folder


def _json_messages(folder: Path) -> list[tuple[str, dict, dict]]:
    with open(folder / "record.mcap", "rb") as f:
        return [(channel.topic, json.loads(schema.data), json.loads(m.data))
                for schema, channel, m in make_reader(f).iter_messages() if channel.message_encoding == "json"]


def test_every_json_schema_loads_in_foxglove():
    json_channels = [c for c in CHANNELS if c.schema_encoding == "jsonschema"]
    assert len(json_channels) == 4
    for c in json_channels:
        assert foxglove_problems(json.loads(c.schema_text), c.schema_name) == []


def test_events_leave_out_what_they_do_not_have(tmp_path):
    events = [d for topic, _, d in _json_messages(_record(tmp_path)) if topic == "/events"]
    assert [sorted(d) for d in events] == [
        ["kind", "reason", "t_ns"], ["cycle", "joint", "kind", "reason", "sent", "t_ns"],  # asked was NaN
        ["category", "cycle", "kind", "reason", "t_ns"]]
    assert all(None not in d.values() for d in events)


def test_every_message_written_fits_its_schema(tmp_path):
    jsonschema = pytest.importorskip("jsonschema")
    messages = _json_messages(_record(tmp_path))
    assert {topic for topic, _, _ in messages} == {"/context", "/events", "/cycles", "/measurements"}
    for topic, schema, d in messages:
        assert schema == json.loads(BY_TOPIC[topic].schema_text)
        jsonschema.Draft202012Validator(schema).validate(d)


def test_a_record_written_with_nulls_reads_as_one_without(tmp_path):
    """Records before this wrote every optional event field, null when absent."""
    _record(tmp_path / "new")
    rewrite(tmp_path / "new", tmp_path / "old",
            edit=lambda topic, d: {**dict.fromkeys(OPTIONAL), **d} if topic == "/events" else d)
    assert any(None in d.values() for topic, _, d in _json_messages(tmp_path / "old") if topic == "/events")
    with open_record(tmp_path / "new") as new, open_record(tmp_path / "old") as old:
        assert list(old.events()) == list(new.events()) and len(list(new.events())) == 3
        assert old.health().ok and new.health().ok
