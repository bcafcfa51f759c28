"""Every parser cellguard owns, fed arbitrary and mutated input, raises nothing but CellguardError.

Parsers: scenario, action map, embodiment profile, replay file (.npz), openpi reply (msgpack).
Mutations start from a valid document and replace one part with any YAML value, so the search
reaches the checks behind the first key instead of stopping at "expected a mapping".
"""

from __future__ import annotations

import copy
import io

import msgpack
import numpy as np
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from cellguard.embodiment.profile import parse_profile
from cellguard.errors import CellguardError
from cellguard.embodiment.action_map import parse_action_map
from cellguard.policy.openpi import decode_reply
from cellguard.policy.replay import read_npz
from cellguard.robot.arm_cell import ASSETS, ArmPickPlace
from cellguard.scenario import parse_scenario
from cellguard.yaml_file import parse_yaml

CELL = ArmPickPlace()
PROFILE_TEXT = (ASSETS / "arm_profile.yaml").read_bytes()
SCENARIO = {"cell": "arm-pick-place", "seed": 7, "policy": "scripted", "acceptance_cycles": 20,
            "faults": [{"kind": "fixture_shift", "at_cycle": 35, "dx_mm": 4.0},
                       {"kind": "servo_gain", "joint": ["elbow"], "factor": 0.85}],
            "guard": {"box": [[0, 0, 0], [1, 1, 1]], "watchdog_s": 0.3}}
ACTION_MAP = {"robot": "arm-pick-place", "actions": [
    {"name": "gripper", "joint": "gripper", "unit": "1", "scale": "23 mm", "offset": "6 mm"},
    {"name": "elbow.pos", "joint": "elbow", "unit": "deg", "sign": -1},
    {"name": "ee.x", "ee": "x", "unit": "mm"}],
    "hold": {"wrist_roll": "0 rad"},
    "ik": {"site": "tcp", "joints": ["shoulder_pan", "shoulder_lift", "wrist_flex"], "mode": "absolute"}}
FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

scalars = st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70), st.floats(allow_nan=True),
                    st.text(max_size=12), st.sampled_from(["0 mm", "1e308 rad", "-0 deg", "nan rad", "1", "%",
                                                           "elbow", "x", "arm-pick-place", "23 mm", "[1]*?"]))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(st.text(max_size=8) | scalars.filter(
                                                           lambda v: v is not None and not isinstance(v, float)),
                                                           inner, max_size=4)), max_leaves=12)


def _paths(doc, prefix=()):
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _paths(v, (*prefix, i))


@st.composite
def mutated(draw, doc):
    """``doc`` with one to three parts replaced by arbitrary values (or removed from their mapping)."""
    doc = copy.deepcopy(doc)
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in _paths(doc) if p]
        if not paths:
            return draw(values)
        path = draw(st.sampled_from(paths))
        parent = doc
        for part in path[:-1]:
            parent = parent[part]
        if isinstance(parent, dict) and draw(st.booleans()):
            del parent[path[-1]]
        else:
            parent[path[-1]] = draw(values)
    return doc


def _only_ours(call, *args):
    try:
        call(*args)
    except CellguardError:
        pass


@FAST
@given(st.one_of(values, mutated(SCENARIO)))
def test_scenario(doc):
    _only_ours(parse_scenario, doc)


@FAST
@given(st.one_of(values, mutated(ACTION_MAP)))
def test_action_map(doc):
    _only_ours(parse_action_map, doc, CELL.profile)


@FAST
@given(st.one_of(mutated(yaml.safe_load(PROFILE_TEXT)).map(lambda d: yaml.safe_dump(d).encode()),
                 st.binary(max_size=200), st.text(max_size=200).map(str.encode)))
def test_profile(text):
    _only_ours(parse_profile, CELL.model, text)


@FAST
@given(st.binary(max_size=300) | st.text(alphabet="[]{}:-&*!|>'\"\n #a1,", max_size=300).map(str.encode))
def test_yaml_text(data):
    _only_ours(parse_yaml, data, "fuzz")


def _npz(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


VALID_NPZ = _npz({"t": np.zeros(2), "actions": np.zeros((2, 3, 6)), "dt": np.array(0.02)})


def _encrypted(data: bytes) -> bytes:
    """The archive with every member flagged encrypted (zipfile then raises a bare RuntimeError)."""
    out = bytearray(data)
    for head, flags in ((b"PK\x03\x04", 6), (b"PK\x01\x02", 8)):
        at = out.find(head)
        while at >= 0:
            out[at + flags] |= 1
            at = out.find(head, at + 1)
    return bytes(out)


@st.composite
def damaged_npz(draw):
    data = bytearray(VALID_NPZ)
    for _ in range(draw(st.integers(1, 8))):
        i = draw(st.integers(0, len(data) - 1))
        data[i] = draw(st.integers(0, 255))
    return bytes(data[:draw(st.integers(0, len(data)))] if draw(st.booleans()) else data)


arrays = st.dictionaries(st.sampled_from(["t", "actions", "uncertainty", "dt", "other"]),
                         st.one_of(st.lists(st.floats(), max_size=5).map(np.array),
                                   st.lists(st.text(max_size=3), max_size=3).map(np.array),
                                   st.integers(0, 4).map(lambda n: np.zeros((n, 2, 6))),
                                   st.integers(0, 3).map(lambda n: np.ones((2, n), dtype=bool))), max_size=4)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(damaged_npz(), arrays.map(_npz), st.binary(max_size=100)))
@example(_encrypted(VALID_NPZ))
def test_replay_file(data):
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "r.npz"
        path.write_bytes(data)
        _only_ours(read_npz, path, "replay", ("t", "actions", "uncertainty", "dt"), ("t", "actions"))


def _ndarray(dtype: str, shape: list, data: bytes) -> dict:
    return {b"__ndarray__": True, b"data": data, b"dtype": dtype, b"shape": shape}


replies = st.one_of(
    st.binary(max_size=200),
    st.builds(lambda dtype, shape, data: msgpack.packb({"actions": _ndarray(dtype, shape, data)}, use_bin_type=True),
              st.sampled_from(["<f4", "<f8", "|O", "<U3", "|V8", "<c8", "|b1", ">i2", "float64", "x"]),
              st.lists(st.integers(-3, 2**40), max_size=3), st.binary(max_size=64)),
    values.map(lambda v: msgpack.packb(v, use_bin_type=True, default=repr)),
)


@FAST
@given(replies)
def test_openpi_reply(data):
    _only_ours(decode_reply, data, "ws://127.0.0.1:1")
