"""``identify --write`` on a profile whose version is a text that looks like a number (``"09"``, ``"0o17"``): the
profile it writes names it as ``previous`` and loads. PyYAML's ``safe_dump`` wrote ``previous: 09`` unquoted, which
the loader reads as the number 9: the written profile was refused ("calibration.previous: expected text, got int")."""

from __future__ import annotations

import pytest
from arm_excitation import ARM, profile  # noqa: F401 (fixtures)

from cellguard.calibrate.write import write_profile
from cellguard.embodiment import load_profile
from cellguard.robot.registry import make_cell


def _result(friction: float, record: str) -> dict:
    """What identify returns, enough for write_profile: one identified elbow friction."""
    return {"records": [record], "estimates": [{"parameter": "friction", "joint": "elbow", "value": friction,
                                                "unit": "N*m", "interval": [friction - 0.01, friction + 0.01]}]}


@pytest.mark.parametrize("version", ["09", "0089", "0o17", "1e3"])
def test_a_version_that_looks_like_a_number_is_kept_as_text_through_two_writes(profile, version):
    cell = make_cell(ARM)
    profile.write_text(profile.read_text().replace('version: "2026-11-01"', f'version: "{version}"', 1))
    assert load_profile(cell.model, profile).version == version
    first = write_profile(profile, cell, _result(0.3, "a"), "2026-11-02")
    assert load_profile(cell.model, profile).calibration.previous == version
    second = write_profile(profile, cell, _result(0.4, "b"), "2026-11-02")  # reads the profile the first wrote
    assert load_profile(cell.model, profile).calibration.previous == first.version != second.version
