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
from cellguard.record.lerobot_export import _exporting_servo_rates, _stride
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


def test_a_stream_no_whole_fps_divides_names_its_rate_and_the_servo_rates_that_export():
    """333 Hz (3 ms) decimates to every 7th tick, 47.619 Hz: no whole rate takes every k-th of those ticks. The error
    said only that, leaving the user to guess at which rate to record instead."""
    with pytest.raises(RecordError) as err:
        _stride({"servo_period_ns": 3_000_000, "record": {"decimated_hz": 50.0}}, 50)
    assert str(err.value) == ("--fps: no whole frame rate divides the record's continuous tick rate 47.619 Hz (1 in 7 "
                              "ticks of its 333.333 Hz servo); a LeRobotDataset's fps is a whole number. Records at "
                              "servo rates of 1000, 500, 250, 200, 100, 50 Hz export (of those whose period is whole "
                              "milliseconds, up to 20 ms)")


@pytest.mark.parametrize("decimated_hz", [50.0, 25.0, 100.0])
def test_the_servo_rates_named_are_exactly_the_whole_millisecond_ones_that_export(decimated_hz):
    """Of sim-server's 1 ms to 20 ms periods, at the default 50 Hz stream, 14 were refused."""
    named = _exporting_servo_rates(decimated_hz)
    for ms in range(1, 21):
        context = {"servo_period_ns": ms * 1_000_000, "record": {"decimated_hz": decimated_hz}}
        try:
            _stride(context, None)
            exports = True
        except RecordError:
            exports = False
        assert exports == (1e3 / ms in named), ms
    if decimated_hz == 50.0:
        assert len(named) == 6



def test_where_no_whole_millisecond_servo_rate_exports_the_error_claims_no_more():
    """At record.decimated_hz 7 a 700 Hz servo exports at 7 fps, but the refusal of a 333 Hz record said no record at
    7 Hz does "(a whole fps is 1 Hz at least)": it speaks of the whole-millisecond periods only, and gives the 1 Hz
    reason only under 1 Hz."""
    assert _stride({"servo_period_ns": 1_428_571, "record": {"decimated_hz": 7.0}}, None) == (1, 7)
    for dt_ns, hz, says in [(3_000_000, 7.0, "6.94444 Hz (1 in 48 ticks of its 333.333 Hz servo)"),
                            (1_000_000, 0.5, "0.5 Hz (1 in 2000 ticks of its 1000 Hz servo)")]:
        with pytest.raises(RecordError) as err:
            _stride({"servo_period_ns": dt_ns, "record": {"decimated_hz": hz}}, None)
        assert str(err.value) == (f"--fps: no whole frame rate divides the record's continuous tick rate {says}; a "
                                  "LeRobotDataset's fps is a whole number. None of the whole-millisecond servo periods "
                                  f"up to 20 ms exports at record.decimated_hz {hz:g}"
                                  + (" (a whole fps is 1 Hz at least)" if hz < 1 else ""))

def test_a_625_hz_record_is_refused_in_one_line_naming_both_rates(tmp_path):
    hz625 = _record(tmp_path / "rec", 16_000_000)
    result = runner.invoke(app, ["record", "to-lerobot", str(hz625), "-o", str(tmp_path / "ds")])
    assert result.exit_code == 2 and not (tmp_path / "ds").exists()
    assert result.output == ("error: --fps: no whole frame rate divides the record's continuous tick rate 62.5 Hz (its "
                             "servo rate); a LeRobotDataset's fps is a whole number. Records at servo rates of 1000, "
                             "500, 250, 200, 100, 50 Hz export (of those whose period is whole milliseconds, up to 20 "
                             "ms)\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec"]


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
