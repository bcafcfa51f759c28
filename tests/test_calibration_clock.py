"""Calibration dates and the wall clock: a profile loads whatever today's clock says (one written while the cell's
clock ran fast stopped the cell once NTP set it right; a host whose clock reset to 1970 could run no cell), and the
dates are checked where they are made instead: identify refuses, before the fit, a record that started after
tomorrow (UTC), and --write never stores a measured date after tomorrow."""

from __future__ import annotations

import contextlib
import datetime as dt
import time

import pytest
import yaml
from arm_excitation import ARM, profile  # noqa: F401 (fixtures)
from cli_util import one_error
from typer.testing import CliRunner

import cellguard.calibrate.identify as identify_module
from cellguard import dates
from cellguard.calibrate.excitation import excitation_scenario, excite
from cellguard.calibrate.identify import CalibrationError
from cellguard.calibrate.write import write_profile
from cellguard.cli import app
from cellguard.fleet.export import oldest_kept
from cellguard.fleet.policy import DataPolicy
from cellguard.record.reader import open_record
from cellguard.robot.registry import make_cell
from cellguard.runtime.build import make_robot
from cellguard.scenario import load_scenario

runner = CliRunner()
FAST_S = 5 * 86400.0  # the cell's clock ran five days fast


@contextlib.contextmanager
def wall_clock_off_by(offset_s: float):
    """The wall clock read ``offset_s`` seconds off (``time.time``/``time_ns``, ``datetime.now``, ``date.today``),
    as on a host whose clock ran fast, or (far negative) whose clock reset to 1970 at boot."""
    real_datetime, real_date, real_time, real_time_ns = dt.datetime, dt.date, time.time, time.time_ns

    class Datetime(real_datetime):
        @classmethod
        def now(cls, tz=None):
            return real_datetime.fromtimestamp(real_time() + offset_s, tz)

    class Date(real_date):
        @classmethod
        def today(cls):
            return real_date.fromtimestamp(real_time() + offset_s)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(time, "time", lambda: real_time() + offset_s)
        mp.setattr(time, "time_ns", lambda: real_time_ns() + int(offset_s * 1e9))
        mp.setattr(dt, "datetime", Datetime)
        mp.setattr(dt, "date", Date)
        yield


def _utc_day(offset_days: int = 0) -> str:
    return (dt.datetime.now(dt.timezone.utc).date() + dt.timedelta(days=offset_days)).isoformat()


def _started(record) -> tuple[str, str]:
    """``record``'s run id and the UTC day it started on, by the clock that recorded it."""
    with open_record(record) as rec:
        return rec.record_id, rec.start_utc[:10]


@pytest.fixture(scope="module")
def fast_record(tmp_path_factory):
    """A 3 s arm excitation recorded while the cell's clock ran five days fast."""
    out = tmp_path_factory.mktemp("fast") / "ex"
    with wall_clock_off_by(FAST_S):
        excite(excitation_scenario(ARM, 3.0), out)
    return out


def _run_with(calibration, tmp_path):
    """The robot a run of the arm with ``calibration: PROFILE`` builds (what `cellguard run` does first)."""
    scenario = tmp_path / "cal.yaml"
    scenario.write_text(yaml.safe_dump({"cell": ARM, "calibration": str(calibration)}))
    return make_robot(load_scenario(scenario))


def test_a_calibration_written_while_the_clock_ran_fast_runs_once_the_clock_is_set(fast_record, profile, tmp_path):
    with wall_clock_off_by(FAST_S):  # the cell calibrates itself with its own fast clock: accepted
        result = runner.invoke(app, ["identify", str(fast_record), "--only", "elbow,friction", "--write",
                                     str(profile)])
    assert result.exit_code == 0, result.output
    ahead = _started(fast_record)[1]
    assert ahead > _utc_day(1)
    assert yaml.safe_load(profile.read_text())["calibration"]["date"] == ahead
    robot = _run_with(profile, tmp_path)  # NTP set the clock right: the cell still runs with its calibration
    assert robot.profile.calibration.date == ahead and robot.profile.version.startswith(f"{ahead}-cal-")
    assert ahead in {m.measured for m in robot.profile.measured}


def test_a_host_whose_clock_reset_to_1970_runs_the_packaged_profile(tmp_path):
    scenario = tmp_path / "short.yaml"
    scenario.write_text(yaml.safe_dump({"cell": ARM}))
    with wall_clock_off_by(2.0 - time.time()):
        assert dt.date.today().year == 1970
        robot = make_robot(load_scenario(scenario))
    assert robot.profile.measured and robot.profile.measured[0].measured == "2026-10-14"


def test_identify_refuses_a_record_from_a_clock_that_ran_ahead_before_the_fit(fast_record, profile, monkeypatch):
    def no_fit(*args, **kwargs):
        raise AssertionError("the fit ran")

    monkeypatch.setattr(identify_module, "identify", no_fit)
    monkeypatch.setattr(identify_module, "refit", no_fit)
    before = profile.read_bytes()
    run, started = _started(fast_record)
    for extra in ([], ["--write", str(profile)], ["--only", "elbow,friction", "--write", str(profile)]):
        line = one_error(runner.invoke(app, ["identify", str(fast_record), *extra]))
        assert line.startswith(f"error: {fast_record}: the start of run {run} is {started}, after tomorrow "
                               f"(today is {_utc_day()}, UTC"), line
        assert "the clock that recorded it ran ahead" in line, line
        assert "measured[" not in line and "arm_profile" not in line, line
    assert profile.read_bytes() == before


def test_write_never_stores_a_measured_date_after_tomorrow(profile):
    before = sorted(p.name for p in profile.parent.iterdir()), profile.read_bytes()
    result = {"records": ["r1"], "estimates": [{"parameter": "friction", "joint": "elbow", "value": 0.3,
                                                "unit": "N*m", "interval": [0.29, 0.31]}]}
    with pytest.raises(CalibrationError, match=rf"--write: the measured date is {_utc_day(2)}, after tomorrow"):
        write_profile(profile, make_cell(ARM), result, _utc_day(2))
    assert (sorted(p.name for p in profile.parent.iterdir()), profile.read_bytes()) == before
    written = write_profile(profile, make_cell(ARM), result, _utc_day(1))  # a site east of UTC is a day ahead
    assert written.version.startswith(f"{_utc_day(1)}-cal-")



def test_identify_and_the_fleet_read_the_utc_date_through_one_helper(monkeypatch):
    """identify kept its own UTC date beside the fleet's (fleet/clock.py): the host's clock read by two copies."""
    monkeypatch.setattr(dates, "utc_now", lambda: dt.datetime(2031, 5, 6, 23, 59, tzinfo=dt.timezone.utc))
    with pytest.raises(CalibrationError, match=r"is 2031-05-08, after tomorrow \(today is 2031-05-06, UTC"):
        identify_module.refuse_ahead("2031-05-08", "the date", "set the clock")
    assert oldest_kept(DataPolicy("ta", "s1", retention_days=1)) == dt.date(2031, 5, 5)
