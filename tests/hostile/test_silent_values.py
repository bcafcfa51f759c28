"""Class 7: values that used to be accepted silently (or coerced) are refused, naming the field."""

from __future__ import annotations

import pytest
import yaml

from .scenarios import BASE, run_refused, scenario_file

SCENARIOS = {
    "duplicate key": ("cell: arm-pick-place\ncell: quadruped-turns\n", "key 'cell' appears twice"),
    "duplicate nested key": ("cell: arm-pick-place\nguard: {watchdog_s: 0.3, watchdog_s: 5}\n", "appears twice"),
    "string for an integer": ({"acceptance_cycles": "1"}, "acceptance_cycles"),
    "boolean for an integer": ({"seed": True}, "seed"),
    "boolean for a stop category": ({"guard": {"watchdog_category": True}}, "guard.watchdog_category"),
    "string for a float": ({"policy_hz": "20"}, "policy_hz"),
    "infinite box": ("cell: arm-pick-place\nguard: {box: [[0, 0, 0], [1, 1, .inf]]}\n", "guard.box[1][2]"),
    "NaN fault size": ("cell: arm-pick-place\nfaults: [{kind: fixture_shift, at_cycle: 1, dx_mm: .nan}]\n",
                       "faults[0].dx_mm"),
    "string fault cycle": ({"faults": [{"kind": "tool_slip", "at_cycle": "5"}]}, "faults[0].at_cycle"),
    "escape codes in site": ({"site": "plant\x1b[2J\x1b]0;owned\x07"}, "site"),
    "newline in a key": ({"cell\nx": 1}, "control characters"),
}


@pytest.mark.parametrize("case", sorted(SCENARIOS))
def test_scenario_values(tmp_path, case):
    content, field = SCENARIOS[case]
    path = (scenario_file(tmp_path, text=content) if isinstance(content, str)
            else scenario_file(tmp_path, **content))
    line = run_refused(tmp_path, path, contains=field)
    assert "\x1b" not in line  # never echoed raw


MAPS = {
    "zero scale": ({"name": "gripper", "joint": "gripper", "unit": "1", "scale": "0 mm"}, "actions[0].scale"),
    "zero numeric scale": ({"name": "gripper", "joint": "gripper", "unit": "m", "scale": 0}, "actions[0].scale"),
    "vanishing scale": ({"name": "gripper", "joint": "gripper", "unit": "1", "scale": "1e-300 mm"}, "actions[0].scale"),
    "boolean sign": ({"name": "gripper", "joint": "gripper", "unit": "m", "sign": True}, "actions[0].sign"),
}


@pytest.mark.parametrize("case", sorted(MAPS))
def test_action_map_values(tmp_path, case):
    """A map whose first action is bad, on an ONNX model named by joint (the map is read when the scenario loads)."""
    pytest.importorskip("onnx")
    from .test_tracebacks import small_onnx

    entry, field = MAPS[case]
    joints = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_flex", "wrist_roll"]
    amap = {"robot": "arm-pick-place", "actions": [entry] + [{"name": j, "joint": j, "unit": "rad"} for j in joints]}
    (tmp_path / "map.yaml").write_text(yaml.safe_dump(amap))
    model = small_onnx(tmp_path / "m.onnx", ",".join(["gripper", *joints]))
    run_refused(tmp_path, scenario_file(tmp_path, policy=f"onnx:{model}?map={tmp_path / 'map.yaml'}"), contains=field)


def test_the_base_scenario_itself_runs():
    """The cases above differ from BASE in one value: BASE must be valid, or they prove nothing."""
    from cellguard.scenario import parse_scenario

    assert parse_scenario(dict(BASE)).cell == "arm-pick-place"
