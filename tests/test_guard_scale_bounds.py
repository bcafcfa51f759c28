"""The speed scale's rate bounds (``guard.scale_rate``, ``guard.scale_accel``) have a floor: ``scale_rate: 1e-300``
was taken, and the playback clock stayed at full speed under reduced speed."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.control.config import GuardConfig
from cellguard.control.envelope import Envelope
from cellguard.robot.protocol import SafetyInputs
from cellguard.robot.registry import make_cell

MS = 1_000_000


def test_the_slowest_slow_down_allowed_reaches_reduced_speed_within_11_s():
    """No tool model: reduced speed asks for the playback scale 0.25, reached at the floors in 8.6 s."""
    cell = make_cell("arm-pick-place")
    q0 = cell.read().q
    envelope = Envelope(cell.profile, q0, MS, GuardConfig(scale_rate=0.1, scale_accel=0.1))
    for k in range(1, 11_001):
        envelope.apply(k * MS, q0, None, SafetyInputs(reduced_speed=True), last_chunk_ns=k * MS)
        if envelope.scale == 0.25:
            break
    assert envelope.scale == 0.25 and 8_000 < k < 11_000, (k, envelope.scale)


@pytest.mark.parametrize("key", ["scale_rate", "scale_accel"])
@pytest.mark.parametrize("value", ["1e-300", "0.09"])
def test_a_scale_rate_or_acceleration_below_its_floor_is_refused_exit_2(tmp_path, key, value):
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text("cell: arm-pick-place\nseed: 1\npolicy: scripted\nacceptance_cycles: 1\nproduction_cycles: 0\n"
                        f"guard: {{{key}: {value}}}\n")
    result = CliRunner().invoke(app, ["run", str(scenario), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and result.stderr.count("\n") == 1, result.output
    assert f"guard.{key}: Input should be greater than or equal to 0.1" in result.stderr
    assert not (tmp_path / "out").exists()
