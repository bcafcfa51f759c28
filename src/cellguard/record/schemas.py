"""The channels of a cellguard record and the schema each one declares.

High-rate data (ticks, action chunks) is CDR with a ``ros2msg`` schema; low-rate data (context,
events, cycle markers, camera and fixture measurements) is JSON with a ``jsonschema``. The recorder
registers the channels in this order, so its channel ids are fixed (1..13); a reader names a channel by the file's
own channel records (``file_ids``: a record rewritten by another MCAP writer numbers them otherwise) and falls back
on the fixed ids only where those records were lost (a record's first chunk holds them).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass

from cellguard.record import ros2
from cellguard.record.cdr import CdrLayout

TICKS = CdrLayout(
    "cellguard_msgs/TickBatch",
    "Consecutive servo ticks of all joints. Arrays are row-major [tick][joint] in `joints` order.\n"
    "SI units: position rad or m, velocity rad/s or m/s, effort N*m or N, current A.",
    (
        ("joints", "string[]", "joint names, profile order"),
        ("t_ns", "int64[]", "tick time [ns], simulated or monotonic clock"),
        ("cycle", "int32[]", "cycle index per tick"),
        ("q_ref", "float32[]", "reference from the executor (what the policy asked)"),
        ("q_cmd", "float32[]", "setpoint actually sent after the envelope and the drive"),
        ("q_meas", "float32[]", "measured position"),
        ("qd_meas", "float32[]", "measured velocity"),
        ("effort", "float32[]", "measured effort"),
        ("current", "float32[]", "measured motor current [A]"),
    ),
)
TICK_FIELDS = ("q_ref", "q_cmd", "q_meas", "qd_meas", "effort", "current")

CHUNK = CdrLayout(
    "cellguard_msgs/ActionChunk",
    "One action chunk as the policy returned it, before the executor or the envelope touched it.\n"
    "Step i targets t_obs_ns + (i + 1) * dt_ns. actions is row-major [horizon][dof].",
    (
        ("t_obs_ns", "int64", "time of the observation the chunk answers [ns]"),
        ("t_received_ns", "int64", "time the chunk reached the executor [ns]"),
        ("latency_ns", "int64", "inference latency [ns]"),
        ("dt_ns", "int64", "step period [ns]"),
        ("dof", "uint32", "action dimension"),
        ("actions", "float32[]", "targets, SI"),
        ("uncertainty", "float32[]", "per-step uncertainty in the policy's scale; empty if none"),
    ),
)


def _json_schema(title: str, properties: dict, required: list[str]) -> dict:
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": title, "type": "object",
            "properties": properties, "required": required}


def _open_object(description: str, values: dict | None = None) -> dict:
    """An object whose keys vary (a context, features by name): Foxglove's JSON-schema parser needs
    ``properties`` on every object, and reads nothing but ``properties``."""
    return {"type": "object", "properties": {}, "description": description,
            **({} if values is None else {"additionalProperties": values})}


# Every field has one type: Foxglove's parser refuses a list of types and an enum without a type. An optional
# field is left out when absent (records before this wrote null there; the reader takes both as absent).
_INT, _NUM, _STR = {"type": "integer"}, {"type": "number"}, {"type": "string"}
_NUM_OR_NULL = {"anyOf": [_NUM, {"type": "null"}], "description": "null: not a finite number"}

CONTEXT_SCHEMA = _json_schema("cellguard.Context", {
    "t_ns": _INT, "epoch_wall_ns": {"type": "integer", "description": "wall clock at t_ns = 0 [ns since 1970]; "
                                                                      "log time = epoch_wall_ns + t_ns"},
    "start_ns": {"type": "integer", "description": "the run clock when the record started [ns]"},
    "record_id": _STR, "record_version": _INT,
    "repeat": {"type": "boolean", "description": "a periodic copy of the unchanged context, for damaged records"},
    "version": _STR, "changed": {"type": "array", "items": _STR},
    "versions": _open_object("policy, calibration, datum", _STR),
    "context": _open_object("policy, embodiment, calibration, envelope, datum, site, software"),
}, ["t_ns", "version", "context"])
EVENT_SCHEMA = _json_schema("cellguard.Event", {
    "t_ns": _INT, "cycle": {"type": "integer", "description": "absent: between cycles"}, "kind": _STR,
    "reason": _STR, "joint": {"type": "string", "description": "absent: no one joint"},
    "asked": {"type": "number", "description": "absent: none, or not finite"},
    "sent": {"type": "number", "description": "absent: none, or not finite"},
    "category": {"type": "integer", "enum": [0, 1, 2], "description": "stop category; absent: no stop"},
    "recovery": {"type": "object", "description": "a recovery_end's attempt, as its cycle's recovery_log entry "
                 "(recorded at once: a killed run's last cycle has no log); absent: not an attempt's end",
                 "properties": {"behaviour": _STR, "trigger": _STR, "attempt": _INT, "outcome": _STR,
                                "duration_s": _NUM, "arrival_s": {**_NUM, "description": "absent: never arrived"},
                                "close_s": {**_NUM, "description": "absent: a plan without contact"}}},
}, ["t_ns", "kind", "reason"])
CYCLE_SCHEMA = _json_schema("cellguard.CycleMarker", {
    "marker": {"type": "string", "enum": ["begin", "end"]}, "cycle": _INT,
    "phase": {"type": "string", "enum": ["acceptance", "production"]},
    "t_start_ns": _INT, "t_end_ns": _INT, "success": {"type": "boolean"}, "context_version": _STR,
    "outcome": _open_object("the cell's measured outcome, SI"),
    "features": _open_object("per-cycle features", _NUM_OR_NULL),
}, ["marker", "cycle", "phase", "t_start_ns"])
MEASUREMENT_SCHEMA = _json_schema("cellguard.Measurements", {
    "t_ns": _INT, "cycle": _INT,
    "measurements": _open_object("camera and fixture readings shown to the policy, SI, sensor frame",
                                 {"type": "array", "items": _NUM}),
}, ["t_ns", "measurements"])


@dataclass(frozen=True)
class ChannelSpec:
    """One channel: topic, and the schema it declares in the file."""

    id: int
    topic: str
    schema_name: str
    schema_encoding: str  # "ros2msg" or "jsonschema"
    schema_text: str
    message_encoding: str  # "cdr" or "json"


def _cdr(i: int, topic: str, layout: CdrLayout) -> ChannelSpec:
    return ChannelSpec(i, topic, layout.name, "ros2msg", layout.ros2msg(), "cdr")


def _json(i: int, topic: str, schema: dict) -> ChannelSpec:
    return ChannelSpec(i, topic, schema["title"], "jsonschema", json.dumps(schema), "json")


def _ros2(i: int, topic: str, message: tuple[str, str]) -> ChannelSpec:
    return ChannelSpec(i, topic, message[0], "ros2msg", message[1], "cdr")


CHANNELS: tuple[ChannelSpec, ...] = (
    _json(1, "/context", CONTEXT_SCHEMA),
    _cdr(2, "/ticks/decimated", TICKS),
    _cdr(3, "/ticks/full", TICKS),
    _cdr(4, "/chunks", CHUNK),
    _json(5, "/events", EVENT_SCHEMA),
    _json(6, "/cycles", CYCLE_SCHEMA),
    _json(7, "/measurements", MEASUREMENT_SCHEMA),
    # standard ROS 2 messages for viewers (record version 2): Foxglove's plot, 3D and log panels
    _ros2(8, "/joint_states", ros2.JOINT_STATE),  # measured, at the decimated rate
    _ros2(9, "/joint_states/full", ros2.JOINT_STATE),  # measured, at servo rate around events
    _ros2(10, "/tf", ros2.TF_MESSAGE),  # moving joints, at the decimated rate
    _ros2(11, "/tf_static", ros2.TF_MESSAGE),  # fixed joints, once
    _ros2(12, "/robot_description", ros2.STRING),  # URDF, once
    _ros2(13, "/events/log", ros2.LOG),  # every event, level by stop category
)
BY_TOPIC = {c.topic: c for c in CHANNELS}
OWN_TOPICS = frozenset(c.topic for c in CHANNELS[:7])  # cellguard's own channels, in every record format


def file_ids(topics: Mapping[int, str]) -> dict[str, int | None]:
    """Each cellguard topic's channel id in a file whose channel records state ``topics`` (id -> topic): its own
    record's (of a topic recorded twice the lowest id), else the fixed id where no record claims that id (the chunk
    holding the records was lost), else None: not in the file."""
    own = {topic: i for i, topic in sorted(topics.items(), reverse=True)}
    return {topic: own.get(topic, None if spec.id in topics else spec.id) for topic, spec in BY_TOPIC.items()}


def not_cellguard(path: object, topics: Mapping[int, str], schema_names: Mapping[int, str] = {}) -> str | None:
    """Why a file whose channel records state ``topics`` is no cellguard record (none of cellguard's own channels:
    read as one, a foreign file was a damaged record with invented details), else None. ``schema_names``: channel id
    -> the name of the schema it declares ("" for none), where known: a channel with one of cellguard's topics and
    another schema, or none (another tool's own /context), is not cellguard's; each topic's schema has kept its name
    since the first record. A channel whose schema record was lost is taken by its topic."""
    names = sorted(set(topics.values()))
    ours = [i for i, topic in topics.items()
            if topic in OWN_TOPICS and schema_names.get(i, BY_TOPIC[topic].schema_name) == BY_TOPIC[topic].schema_name]
    if not names or ours:
        return None
    shown = ", ".join(names[:10]) + (f", ... ({len(names)} topics)" if len(names) > 10 else "")
    return f"{path}: not a cellguard record (no cellguard channel; its topics: {shown})"
