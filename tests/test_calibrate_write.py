"""``identify --write`` under concurrency, with YAML dates, and dated by its records: two writes at once take turns
(neither calibration lost), a re-fit whose profile changed meanwhile is refused, an unquoted date is text, and
the calibration is dated by the records' start in UTC, not by the local clock."""

from __future__ import annotations

import datetime as dt
import fcntl
import json
import os
import threading
import time
from pathlib import Path

import pytest
import yaml
from arm_excitation import ARM, excited, profile  # noqa: F401 (fixtures)
from cli_util import one_error
from typer.testing import CliRunner

from cellguard.calibrate.identify import CalibrationError
from cellguard.calibrate.write import write_profile
from cellguard.cli import app
from cellguard.embodiment import load_profile
from cellguard.errors import ProfileError
from cellguard.record.reader import open_record
from cellguard.robot.registry import make_cell

runner = CliRunner()


def _result(friction: float, record: str) -> dict:
    """What identify returns, enough for write_profile: one identified elbow friction."""
    return {"records": [record], "estimates": [{"parameter": "friction", "joint": "elbow", "value": friction,
                                                "unit": "N*m", "interval": [friction - 0.01, friction + 0.01]}]}


def _calibration(profile: Path) -> dict:
    return yaml.safe_load(profile.read_text())["calibration"]


def test_a_second_write_waits_for_the_first_and_names_its_version(profile):
    cell = make_cell(ARM)
    before = profile.read_bytes()
    done = {}
    fd = os.open(profile.parent, os.O_RDONLY)
    fcntl.flock(fd, fcntl.LOCK_EX)  # a first writer holds the folder
    try:
        waiting = threading.Thread(target=lambda: done.setdefault("b", write_profile(profile, cell, _result(0.3, "b"),
                                                                                     "2026-11-02")))
        waiting.start()
        time.sleep(0.5)
        assert waiting.is_alive() and profile.read_bytes() == before  # it waits: nothing read or written yet
    finally:
        os.close(fd)
    waiting.join(30)
    assert _calibration(profile)["version"] == done["b"].version


def test_a_folder_that_refuses_locks_is_one_line_and_the_profile_stays(profile, monkeypatch):
    """flock on an NFS mount without its lock daemon raises ENOLCK: a traceback, exit 1."""
    def no_locks(fd, op):
        raise OSError(37, "No locks available")

    before = profile.read_bytes()
    monkeypatch.setattr(fcntl, "flock", no_locks)
    with pytest.raises(ProfileError, match="cannot lock the profile's folder .* \\(No locks available\\)"):
        write_profile(profile, make_cell(ARM), _result(0.3, "b"), "2026-11-02")
    assert profile.read_bytes() == before


def test_two_writes_at_once_keep_both_calibrations_in_one_chain(profile):
    cell = make_cell(ARM)
    written: dict[str, object] = {}
    threads = [threading.Thread(target=lambda k=k, f=f: written.setdefault(k, write_profile(
        profile, cell, _result(f, k), "2026-11-02"))) for k, f in (("a", 0.3), ("b", 0.4))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    last = _calibration(profile)
    first = next(w for w in written.values() if w.version != last["version"])
    assert last["previous"] == first.version  # the second wrote on top of the first, naming it
    kept = yaml.safe_load(profile.with_name(f"arm_profile.{first.version}.yaml").read_text())
    assert kept["calibration"]["previous"] == "2026-11-01"
    assert {w.mjcf.name for w in written.values()} <= {p.name for p in profile.parent.iterdir()}


def test_a_refit_whose_profile_changed_meanwhile_is_refused(profile):
    cell = make_cell(ARM)
    basis = profile.read_bytes()
    write_profile(profile, cell, _result(0.3, "a"), "2026-11-02")  # another calibration lands during the re-fit
    after = profile.read_bytes()
    with pytest.raises(CalibrationError, match="changed while the re-fit ran"):
        write_profile(profile, cell, _result(0.4, "b"), "2026-11-02", basis=basis)
    assert profile.read_bytes() == after


def test_an_unquoted_date_is_text_and_the_write_goes_through(profile):
    text = profile.read_text().replace('measured: "2026-10-14"', "measured: 2026-10-14")
    assert "measured: 2026-10-14," in text
    profile.write_text(text)
    written = write_profile(profile, make_cell(ARM), _result(0.3, "a"), "2026-11-02")  # json.dumps met a date
    measured = load_profile(make_cell(ARM).model, profile).measured
    assert {m.measured for m in measured} == {"2026-10-14", "2026-11-02"} and "-cal-" in written.version


def test_the_calibration_is_dated_by_its_records_in_utc(excited, profile, monkeypatch):
    with open_record(excited) as rec:
        day = dt.datetime.fromtimestamp(rec.start_wall_ns / 1e9, dt.timezone.utc).date().isoformat()
    # a zone whose local date is not the UTC date now: west of UTC before noon UTC, east of it after 10:00 UTC
    zone = "Etc/GMT+12" if dt.datetime.now(dt.timezone.utc).hour < 12 else "Etc/GMT-14"
    monkeypatch.setenv("TZ", zone)
    time.tzset()
    try:
        assert dt.date.today().isoformat() != day
        result = runner.invoke(app, ["identify", str(excited), "--only", "elbow,friction", "--only", "elbow,friction",
                                     "--write", str(profile), "--json"])
    finally:
        monkeypatch.delenv("TZ")
        time.tzset()
    assert result.exit_code == 0, result.output
    assert len(json.loads(result.output)["estimates"]) == 1  # the pair given twice is fitted once
    calibration = _calibration(profile)
    assert calibration["date"] == day and calibration["version"].startswith(f"{day}-cal-")
    elbow = next(m for m in load_profile(make_cell(ARM).model, profile).measured
                 if (m.joint, m.parameter) == ("elbow", "friction"))
    assert elbow.measured == day


def test_only_with_a_profile_of_another_robot_names_write(excited, profile):
    profile.write_text(profile.read_text().replace("robot: arm-pick-place", "robot: quadruped-turns"))
    line = one_error(runner.invoke(app, ["identify", str(excited), "--only", "elbow,friction", "--write",
                                         str(profile)]))
    assert line.startswith("error: --write: ") and "--profile" not in line, line
