"""A profile's text fields must be text: ``str()`` turned ``robot: [1]`` into the robot "[1]"."""

from __future__ import annotations

import pytest
import yaml

from cellguard.embodiment import load_profile
from cellguard.errors import ProfileError
from cellguard.robot.arm_cell import ASSETS

CALIBRATION = {"version": "v2", "mjcf": "arm.v2.xml", "date": "2026-11-02", "records": ["r1"], "previous": "v1"}


@pytest.mark.parametrize(("edit", "message"), [
    (lambda r: r.__setitem__("robot", [1]), "robot: expected text, got list"),
    (lambda r: r.__setitem__("version", {"a": 1}), "version: expected text, got dict"),
    (lambda r: r["measured"][3].__setitem__("method", [1]), "measured[3].method: expected text, got list"),
    (lambda r: r["measured"][0].__setitem__("parameter", 7), "measured[0].parameter: expected text, got int"),
    (lambda r: r.__setitem__("calibration", {**CALIBRATION, "previous": [1]}),
     "calibration.previous: expected text, got list"),
])
def test_a_text_field_of_another_type_names_the_file_and_the_field(arm, tmp_path, edit, message):
    raw = yaml.safe_load((ASSETS / "arm_profile.yaml").read_text())
    edit(raw)
    path = tmp_path / "profile.yaml"
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(ProfileError) as info:
        load_profile(arm.model, path)
    assert str(info.value) == f"{path}: {message}"

