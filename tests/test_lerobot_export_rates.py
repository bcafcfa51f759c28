"""``record to-lerobot --fps`` on records whose tick period is not a whole number of nanoseconds per frame.

LeRobot's usual 30 Hz is 33,333,333 ns a tick: 30 fps takes every tick of it, though 1/30 s is 33,333,333.3 ns.
"""

from __future__ import annotations

import json

import pytest
from record_synth import JOINTS, context, values
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.errors import RecordError
from cellguard.record.lerobot_export import _stride
from cellguard.record.reader import open_record
from cellguard.record.writer import RecordConfig, Recorder
from cellguard.robot.state import State

runner = CliRunner()


def _record(folder, dt_ns: int, cycles: int = 2, ticks_per_cycle: int = 40):
    """``cycles`` completed cycles at the servo period ``dt_ns`` (the default 50 Hz decimated stream)."""
    config = RecordConfig()
    rec = Recorder.create(folder, joints=JOINTS, dt_ns=dt_ns, context=context(servo_period_ns=dt_ns,
                          record=config.to_dict()), config=config, epoch_wall_ns=1_790_000_000_000_000_000)
    k = 0
    for c in range(cycles):
        rec.cycle_begin(c, "acceptance", k * dt_ns)
        for _ in range(ticks_per_cycle):
            v = values(k)
            rec.tick(c, v["q_ref"], v["q_cmd"], State(k * dt_ns, v["q_meas"], v["qd_meas"], v["effort"], v["current"]))
            k += 1
        rec.cycle_end({"cycle": c, "phase": "acceptance", "success": True, "features": {}}, k * dt_ns)
    rec.close()
    return folder


@pytest.fixture(scope="module")
def hz30(tmp_path_factory):
    return _record(tmp_path_factory.mktemp("hz30"), 33_333_333)


@pytest.mark.parametrize("fps, stride", [(30, 1), (15, 2), (10, 3)])
def test_a_30_hz_record_exports_at_30_fps_and_its_whole_divisors(hz30, tmp_path, fps, stride):
    result = runner.invoke(app, ["record", "to-lerobot", str(hz30), "-o", str(tmp_path / "ds"), "--fps", str(fps)])
    assert result.exit_code == 0, result.output
    with open_record(hz30) as rec:
        ticks = [rec.ticks(cycle=c, rate="decimated") for c in range(2)]
    info = json.loads((tmp_path / "ds/meta/info.json").read_text())
    assert info["fps"] == fps and info["total_episodes"] == 2 and "skipped" not in result.output
    assert info["total_frames"] == sum(len(t.t_ns[::stride]) for t in ticks) == 2 * len(range(0, 40, stride))


def test_without_fps_a_30_hz_record_exports_at_its_own_rate(hz30, tmp_path):
    """The default was 50 fps: every 30 Hz record (LeRobot's usual rate) needed --fps to export at all."""
    result = runner.invoke(app, ["record", "to-lerobot", str(hz30), "-o", str(tmp_path / "ds")])
    assert result.exit_code == 0, result.output
    assert json.loads((tmp_path / "ds/meta/info.json").read_text())["fps"] == 30 and "at 30 fps" in result.output


def test_an_fps_that_does_not_divide_names_only_whole_rates_that_do(hz30, tmp_path):
    result = runner.invoke(app, ["record", "to-lerobot", str(hz30), "-o", str(tmp_path / "ds"), "--fps", "50"])
    assert result.exit_code == 2 and not (tmp_path / "ds").exists()
    assert result.output == "error: --fps: 50 must divide the record's continuous tick rate 30 Hz (e.g. 30, 15, 10)\n"


@pytest.mark.parametrize("dt_ns, fps, stride", [(16_666_667, 30, 2), (8_333_333, 60, 1), (8_333_333, 20, 3),
                                                 (1_000_000, 50, 1), (1_000_000, 25, 2), (20_000_000, 10, 5)])
def test_stride_at_servo_rates_that_are_not_whole_nanoseconds(dt_ns, fps, stride):
    assert _stride({"servo_period_ns": dt_ns, "record": {"decimated_hz": 50.0}}, fps) == (stride, fps)


def test_a_stream_no_whole_fps_divides_suggests_none():
    """333 Hz (3 ms) decimates to every 7th tick, 47.619 Hz: no whole rate takes every k-th of those ticks."""
    with pytest.raises(RecordError) as err:
        _stride({"servo_period_ns": 3_000_000, "record": {"decimated_hz": 50.0}}, 50)
    assert str(err.value).startswith("--fps: no whole frame rate divides the record's continuous tick rate 47.619 Hz")
    assert "e.g." not in str(err.value)


def test_suggested_rates_are_accepted():
    context = {"servo_period_ns": 8_333_333, "record": {"decimated_hz": 50.0}}  # 120 Hz: 60 Hz decimated
    with pytest.raises(RecordError, match=r"\(e\.g\. 60, 30, 20\)$"):
        _stride(context, 50)
    assert [_stride(context, fps)[0] for fps in (60, 30, 20)] == [1, 2, 3]


def test_whole_rates_are_tried_per_frame_rate_up_to_1000():
    """A context stating a 1 ns tick ran k to 10^9 (145 s before an answer); a 60 Hz stream offers 60 itself."""
    from cellguard.record.lerobot_export import _whole_rates

    assert _stride({"servo_period_ns": 1, "record": {"decimated_hz": 1e8}}, None)[1] == 1000
    assert _whole_rates(16_666_667)[:2] == [60, 30]
