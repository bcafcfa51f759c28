"""Findings of a hostile probe of cellguard's inputs: openpi metadata, names against output width, YAML merge keys,
replay's --vary on a slide joint, and a ``+`` in a spec's option."""

from __future__ import annotations

import copy
import hashlib
import json
import os

import msgpack
import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hostile.scenarios import run_refused, scenario_file
from cellguard.calibrate.identify import CalibrationError
from cellguard.calibrate.replay import parse_vary
from cellguard.errors import ConfigError
from cellguard.options import split_options
from cellguard.policy.metadata_hash import MAX_DEPTH
from cellguard.policy.registry import make_policy
from cellguard.robot.arm_cell import ArmPickPlace
from cellguard.scenario import load_scenario
from cellguard.yaml_file import parse_yaml

NAMES = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex", "wrist_roll", "gripper"]
URI = "ws://127.0.0.1:1"
FAST = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _old_sha256(uri: str, metadata: dict) -> str:
    """The hash releases pinned before: what it hashed must hash the same."""
    meta = {k: v for k, v in metadata.items() if isinstance(v, (str, int, float, list, bool))}
    return hashlib.sha256(json.dumps({"uri": uri, "metadata": meta}, sort_keys=True).encode()).hexdigest()


def _serve(metadata: dict):
    """A real websocket server on 127.0.0.1 sending ``metadata`` (openpi's msgpack) on connect; yields its URI."""
    pytest.importorskip("websockets")
    from hostile.wsserver import serve_bytes

    from cellguard.policy.wire import packb

    return serve_bytes(packb(metadata), packb({"actions": np.zeros((10, 6))}))


def _arrived(metadata: dict) -> dict:
    """``metadata`` (with an action_dim) as an openpi connection to a real server receives it; the hash a run records
    of it taken on the way (a run and a release create took it, and raised)."""
    from cellguard.policy.openpi import OpenpiBackend

    with _serve({**metadata, "action_dim": 6, "dt_s": 0.05}) as uri:
        backend = OpenpiBackend(uri, None, 2.0, 0)
        try:
            assert len(backend.content_hash()) == 64
            return backend.metadata
        finally:
            backend.close()


def _sha256(metadata: dict) -> str:
    """The metadata's hash as a release pins it, for one URI (each test server has its own port)."""
    from cellguard.policy.metadata_hash import metadata_sha256

    return metadata_sha256(URI, metadata)


# 1. openpi metadata: hashed canonically, or refused in one line

@pytest.mark.parametrize("extra", [
    {"action_scale": [np.float32(1.0)] * 6},  # openpi's msgpack_numpy makes numpy scalars of numpy metadata
    {"tags": [b"x"]},
    {1: "x"},
    {None: 1},
    {"norm": [{"mean": np.arange(6.0), "std": np.ones(6, ">f4")}]},
])
def test_openpi_metadata_that_crashed_the_hash_is_hashed_the_same_on_every_connection(extra):
    with _serve({"action_names": NAMES, "dt_s": 0.05, **extra}) as uri:
        hashes = set()
        for _ in range(2):
            policy = make_policy(f"openpi:{uri}", ArmPickPlace())
            hashes.add(policy.content_hash())
            policy.close()
    assert len(hashes) == 1 and len(hashes.pop()) == 64


def test_a_server_sending_the_same_metadata_in_another_order_hashes_the_same():
    meta = {"action_names": NAMES, "dt_s": 0.05, "x": [{2: "b", None: "a", "k": np.float32(2)}], 7: "seven"}
    assert _sha256(_arrived(meta)) == _sha256(_arrived(dict(reversed(meta.items()))))


def test_metadata_it_cannot_hash_is_one_line_exit_2_naming_the_key(tmp_path):
    with _serve({"action_names": NAMES, "dt_s": 0.05, "stamp": [msgpack.Timestamp(1, 2)]}) as uri:
        line = run_refused(tmp_path, scenario_file(tmp_path, policy=f"openpi:{uri}"))
    assert line == (f"error: policy: openpi:{uri}: server metadata 'stamp' holds a Timestamp, which cannot be hashed "
                    f"for the release's pin of the server; have the server send numbers, text, bytes, lists, maps or "
                    f"numpy arrays")


_DTYPES = ["<f4", ">f4", "<f8", "<i8", ">i2", "|u1", "|b1", "<f2"]
_INTS = st.integers(-2**63, 2**64 - 1)  # msgpack's
_SCALARS = (st.none() | st.booleans() | _INTS | st.floats(allow_nan=True) | st.text(max_size=8) | st.binary(max_size=8)
            | st.builds(lambda d, x: np.array(x).astype(d)[()], st.sampled_from(_DTYPES), st.integers(0, 100))
            | st.builds(lambda d, xs: np.array(xs).astype(d), st.sampled_from(_DTYPES),
                        st.lists(st.integers(0, 100), max_size=4)))
_KEYS = (st.none() | st.booleans() | st.integers(-5, 5) | st.floats(allow_nan=True) | st.text(max_size=4)
         | st.binary(max_size=3) | st.builds(np.float32, st.integers(0, 3)))
_VALUES = st.recursive(_SCALARS, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(_KEYS, inner, max_size=4),
                       max_leaves=20)
_JSON = st.recursive(st.none() | st.booleans() | _INTS | st.floats() | st.text(max_size=8),  # what json.dumps takes
                     lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=4), inner,
                                                                                 max_size=4), max_leaves=20)


def _reordered(value):
    """``value`` with every map's entries in reverse order: the same metadata, written another way."""
    if isinstance(value, dict):
        return {k: _reordered(v) for k, v in reversed(list(value.items()))}
    return [_reordered(v) for v in value] if isinstance(value, list) else copy.deepcopy(value)


@FAST
@given(st.dictionaries(_KEYS, _VALUES, max_size=5))
def test_any_metadata_hashes_deterministically_whatever_its_maps_order(metadata):
    arrived = _arrived(metadata)
    assert _sha256(arrived) == _sha256(_reordered(arrived)) == _sha256(copy.deepcopy(arrived))


@FAST
@given(st.dictionaries(st.text(max_size=6), _JSON, max_size=5))
def test_metadata_the_old_hash_took_hashes_as_before(metadata):
    """A release pinned before this change still verifies."""
    arrived = _arrived(metadata)
    assert _sha256(arrived) == _old_sha256(URI, arrived)


def _nested(depth: int) -> list:
    value: list = []
    for _ in range(depth):
        value = [value]
    return value


@FAST
@given(st.dictionaries(st.text(max_size=4), _VALUES, max_size=3),
       st.sampled_from([msgpack.ExtType(5, b"ab"), msgpack.Timestamp(1, 2), _nested(MAX_DEPTH + 1)]))
def test_a_value_with_no_canonical_form_is_the_one_clear_error(metadata, bad):
    with pytest.raises(ConfigError, match=r"^policy: openpi:ws://127\.0\.0\.1:\d+: server metadata 'bad' holds "):
        _arrived({**metadata, "bad": [bad]})


def test_a_value_is_hashed_with_its_dtype_and_by_value_not_byte_order():
    def digest(value):
        return _sha256(_arrived({"v": [value]}))

    assert digest(np.float32(1.0)) != digest(1.0) == digest(np.float64(1.0))  # float64 is a float: as before
    assert digest(b"x") != digest("x")
    assert digest(np.arange(3, dtype="<f8")) == digest(np.arange(3, dtype=">f8")) != digest(np.arange(3, dtype="<f4"))
    assert digest({1: "a"}) != digest({2: "a"})


# 2. names against output width

def test_openpi_metadata_naming_six_actions_but_giving_action_dim_5_says_so():
    with _serve({"action_names": NAMES, "action_dim": 5, "dt_s": 0.05}) as uri, pytest.raises(ConfigError) as caught:
        make_policy(f"openpi:{uri}", ArmPickPlace())
    assert str(caught.value) == (f"policy: openpi:{uri} names 6 actions but outputs 5 per step; its action names and "
                                 f"its output must agree")


def test_an_onnx_model_naming_two_of_its_six_actions_is_one_line_exit_2(tmp_path):
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    from cellguard.policy.onnx_export import Mlp, save_mlp_onnx

    mlp = Mlp(inputs=(("time_s", 1),), weights=(np.zeros((1, 4)), np.zeros((4, 60))),
              biases=(np.zeros(4), np.zeros(60)), x_mean=np.zeros(1), x_std=np.ones(1), y_mean=np.zeros(60),
              y_std=np.ones(60), horizon=10)
    model = save_mlp_onnx(mlp, tmp_path / "two.onnx", {"cellguard.dt_s": "0.05", "cellguard.action_names": "a,b"})
    line = run_refused(tmp_path, scenario_file(tmp_path, policy=f"onnx:{model}"))
    assert line == f"error: policy: onnx:{model} names 2 actions but outputs 6 per step; its action names and its " \
                   f"output must agree"


# 3. YAML merge keys

def test_a_merge_key_merges_and_an_explicit_key_overrides_it():
    text = "defaults: &d {seed: 3, cell: a}\nrun:\n  <<: *d\n  cell: b\n"
    assert parse_yaml(text, "s.yaml") == {"defaults": {"seed": 3, "cell": "a"}, "run": {"seed": 3, "cell": "b"}}


@pytest.mark.parametrize("lines", [
    # a chain, each merging the one before and adding a key: quadratically many copies (143 kB: 12 s, 316 MB)
    ["m0: &m0 {k0: 0}"] + [f"m{i}: &m{i} {{<<: *m{i - 1}, k{i}: 0}}" for i in range(1, 4000)],
    # each merging the one before twice, its unhashable key never one twice: doubling (700 bytes: 5 s, 76 MB; 30
    # levels: 20 minutes)
    ["defs:", "  d:", "    base: &m0 {? [1] : x}"] + [f"    m{i}: &m{i} {{<<: [*m{i - 1}, *m{i - 1}]}}"
                                                     for i in range(1, 40)] + ["use: {<<: *m39}"],
], ids=["chain", "doubling"])
def test_merge_keys_that_copy_past_the_value_limit_are_refused_as_they_copy(lines):
    """The document's value limit was checked once it was built: merges copied first."""
    with pytest.raises(ConfigError, match="merge keys copy more than 1000000 keys"):
        parse_yaml("\n".join(lines) + "\n", "bomb")


def test_a_scenario_shares_a_fault_through_a_merge_key(tmp_path):
    path = scenario_file(tmp_path, "cell: arm-pick-place\nacceptance_cycles: 0\nproduction_cycles: 2\nfaults:\n"
                                   "  - &f {kind: tool_slip, at_cycle: 0, dx_mm: 2.0}\n  - {<<: *f, at_cycle: 1}\n")
    assert [(f.at_cycle, f.dx_mm) for f in load_scenario(path).faults] == [(0, 2.0), (1, 2.0)]


@pytest.mark.parametrize(("text", "says"), [
    ("d: &d {a: 1}\ns: {<<: *d, b: 1, b: 2}\n", "s.yaml: line 2: key 'b' appears twice in one mapping"),
    ("d: &d {a: 1}\ns: {<<: *d, <<: *d}\n",
     "s.yaml: line 2: key '<<' appears twice in one mapping; merge several with <<: [*a, *b]"),
    ("d: &d {<<: *d}\n", "s.yaml: line 1: a mapping merges itself (<< names its own anchor)"),
    ("d: &d [1]\ns: {<<: *d}\n",
     "s.yaml: not valid YAML at line 2 (expected a mapping or list of mappings for merging)"),
])
def test_a_key_written_twice_beside_a_merge_or_a_bad_merge_is_one_line(text, says):
    with pytest.raises(ConfigError) as caught:
        parse_yaml(text, "s.yaml")
    assert str(caught.value) == says


_KEY = st.sampled_from(["x", "y", "seed", "production_cycles", "a_rather_long_key_name"])
_MAP = st.dictionaries(_KEY, st.integers(0, 9), max_size=4)


def _flow(mapping: dict) -> str:
    return "{" + ", ".join(f"{k}: {v}" for k, v in mapping.items()) + "}"


@FAST
@given(st.lists(_MAP, min_size=1, max_size=3), _MAP, st.booleans())
def test_merged_keys_follow_yaml_merge_precedence(sources, own, chained):
    """Own keys override merged ones; of ``<<: [*a, *b]`` the earlier overrides the later; a mapping merged into a
    third holds what it resolved to (``chained``: ``m`` merges ``s0`` and is itself merged)."""
    anchors = "".join(f"s{i}: &s{i} {_flow(s)}\n" for i, s in enumerate(sources))
    merge = ", ".join(f"*s{i}" for i in range(len(sources)))
    text = f"{anchors}m: &m {{<<: [{merge}]{', ' if own else ''}{_flow(own)[1:-1]}}}\n"
    expected = {}
    for source in reversed(sources):
        expected.update(source)
    expected.update(own)
    if chained:
        text += "c: {<<: *m}\n"
    document = parse_yaml(text, "s.yaml")
    assert document["m"] == expected and (not chained or document["c"] == expected)
    if len(sources) == 1 and not chained:  # where PyYAML's own merge is right, it agrees
        assert document == yaml.safe_load(text)


# 4. replay --vary on a slide joint

def test_vary_on_the_gripper_says_replay_varies_hinge_joints_only():
    with pytest.raises(CalibrationError) as caught:
        parse_vary("damping:gripper=0.5..2", ArmPickPlace())
    assert str(caught.value) == ("--vary: 'gripper' is a slide joint of the arm-pick-place model; replay varies hinge "
                                 "joints only (the joints identify measures, whose currents the replay compares); "
                                 "allowed: shoulder_pan, shoulder_lift, elbow, wrist_flex, wrist_roll")


# 5. a + in an option is a +

def test_a_plus_in_a_file_name_is_kept_and_in_text_a_space_as_before():
    """A file's name is percent-decoded only; a prompt or task keeps form decoding (``pick+up`` is "pick up"): a
    release frozen with ``prompt=pick+the+cube`` would have run with other words, and no hash would have said so."""
    assert split_options("x?map=a+b.yaml&prompt=pick+the%20cube%2B&units=c+d.yaml", None, "policy: x", "x:T")[1] == {
        "map": "a+b.yaml", "prompt": "pick the cube+", "units": "c+d.yaml"}


@pytest.mark.parametrize("name", ["a+b.yaml", "a b.yaml"])
def test_a_scenarios_map_named_with_a_plus_or_a_space_is_that_file_beside_it(tmp_path, name):
    pytest.importorskip("onnxruntime")
    (tmp_path / name).write_text("x")
    path = scenario_file(tmp_path, policy=f"onnx:m.onnx?map={name.replace(' ', '%20')}&dt=0.05")
    policy = load_scenario(path).policy
    assert split_options(policy.partition(":")[2], None, "policy", "x")[1]["map"] == os.path.realpath(tmp_path / name)
