"""identify reads every tick value it fits from or it says why not. A finite but absurd measured velocity (3e38 rad/s
on one tick of elbow) was fitted as a measurement and written as a calibration (exit 0); a NaN or infinite measured
position or setpoint, and a fitted joint's current missing on some ticks, were dropped with those ticks, unsaid. Now a
velocity beyond 100 times the joint's limit, and a position, setpoint or current that is not finite (a current NaN
excepted: a reading the drive did not report) are refused in one line naming record, field, joint and tick (exit 2,
nothing written); a fitted joint's NaN currents leave their ticks out, and a warning says how many and why."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from arm_excitation import excited, profile  # noqa: F401 (fixtures)
from cli_util import one_error
from record_synth import rewrite
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.schemas import TICKS

runner = CliRunner()
T_NS = 1_501_000_000  # the tick made bad: inside the 3 s excitation, past its fade-in


def with_value(source: Path, target: Path, field: str, joint: str, value: float, ticks: int = 1, every: int = 1,
               start: int = T_NS) -> Path:
    """A copy of the record in ``source`` whose ``joint``'s ``field`` is ``value`` on ``ticks`` ticks from ``start``
    [ns], one in ``every`` (1 ms apart), in every tick stream that carries them, written through the mcap Writer (a
    record from another writer)."""
    edited = []

    def edit(topic: str, data: bytes) -> bytes:
        if not topic.startswith("/ticks"):
            return data
        batch = TICKS.decode(data)
        t_ns = np.asarray(batch["t_ns"])
        hit = np.flatnonzero((t_ns >= start) & (t_ns < start + ticks * every * 1_000_000)
                             & ((t_ns - start) // 1_000_000 % every == 0))
        if not len(hit):
            return data
        column = np.array(batch[field], dtype=np.float32).reshape(len(t_ns), -1)
        column[hit, list(batch["joints"]).index(joint)] = value
        edited.append(topic)
        return TICKS.encode(batch | {field: column.ravel()})

    rewrite(source, target, edit_bytes=edit)
    assert edited, "no tick stream carries the tick"
    return target


def files(folder: Path) -> list[tuple[str, bytes]]:
    return sorted((p.name, p.read_bytes()) for p in folder.iterdir() if p.is_file())


@pytest.mark.parametrize("value", [3e38, -3e38, 301.0])
def test_a_velocity_beyond_any_the_joint_reaches_is_refused_naming_record_joint_and_tick(excited, profile, tmp_path,
                                                                                          value):
    bad = with_value(excited, tmp_path / "bad", "qd_meas", "elbow", value)
    before = files(profile.parent)
    line = one_error(runner.invoke(app, ["identify", str(bad), "--write", str(profile)]))
    shown = f"{np.float32(value):g}"
    assert line.startswith(f"error: {bad}: run ") and f"measured velocity (qd_meas) of elbow is {shown} rad/s at " \
        f"tick t_ns {T_NS}, beyond 100 times its limit of 3 rad/s (1 of " in line, line
    assert files(profile.parent) == before  # nothing written


def test_a_velocity_within_100_times_the_limit_is_fitted(excited, tmp_path):
    """299 rad/s on one tick of elbow (limit 3 rad/s) is read as the measurement it may be (a spike of the
    encoder's differentiation): the bound refuses only what no joint of the profile could do."""
    odd = with_value(excited, tmp_path / "odd", "qd_meas", "elbow", 299.0)
    result = runner.invoke(app, ["identify", str(odd), "--params", "kp"])
    assert result.exit_code == 0, result.output


@pytest.mark.parametrize(("field", "words"), [("q_meas", "measured position (q_meas)"),
                                              ("q_cmd", "setpoint sent (q_cmd)"),
                                              ("current", "motor current (current)")])
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_a_position_setpoint_or_current_not_finite_is_refused_naming_record_joint_and_tick(excited, profile,
                                                                                            tmp_path, field, words,
                                                                                            value):
    if field == "current" and np.isnan(value):
        pytest.skip("a NaN current is a reading the drive did not report: left out, and said (test below)")
    bad = with_value(excited, tmp_path / "bad", field, "wrist_flex", value)
    before = files(profile.parent)
    line = one_error(runner.invoke(app, ["identify", str(bad), "--write", str(profile)]))
    assert line.startswith(f"error: {bad}: run ") and f"{words} of wrist_flex is {value} at tick t_ns {T_NS} (1 of " \
        in line, line
    assert files(profile.parent) == before  # nothing written


def test_the_ticks_a_fitted_joints_current_is_missing_on_are_left_out_and_counted(excited, tmp_path):
    """25 ticks without elbow's current: the fit goes on without them, and its output says so (JSON and text)."""
    gaps = with_value(excited, tmp_path / "gaps", "current", "elbow", np.nan, ticks=25)
    whole = json.loads(runner.invoke(app, ["identify", str(excited), "--params", "kp", "--json"]).stdout)
    result = runner.invoke(app, ["identify", str(gaps), "--params", "kp", "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.stdout)
    said = [w for w in out["warnings"] if "left out" in w]
    assert said == [f"{gaps}: 25 of {whole['samples']} ticks of run {out['records'][0]} left out: no motor current "
                    f"(NaN) on elbow on 25 ticks from t_ns {T_NS} (a drive that did not report it), and the stretches "
                    "between them shorter than 200 ticks"], out["warnings"]
    assert out["samples"] == whole["samples"] - 25
    text = runner.invoke(app, ["identify", str(gaps), "--params", "kp"])
    assert text.exit_code == 0 and f"warning: {said[0]}" in text.output.splitlines(), text.output
    assert not [w for w in whole["warnings"] if "left out" in w]


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_a_velocity_that_is_not_finite_is_refused_naming_record_joint_and_tick(excited, profile, tmp_path, value):
    """One NaN of elbow's qd_meas made the least-squares solve fail in a traceback ("SVD did not converge")."""
    bad = with_value(excited, tmp_path / "bad", "qd_meas", "elbow", value)
    before = files(profile.parent)
    line = one_error(runner.invoke(app, ["identify", str(bad), "--write", str(profile)]))
    assert line.startswith(f"error: {bad}: run ") and "measured velocity (qd_meas) of elbow is " in line, line
    assert f"is {value} at tick t_ns {T_NS} (1 of " in line, line
    assert files(profile.parent) == before  # nothing written
    # without --write as well: a fit of the drives alone read every joint's velocity
    assert "of elbow is" in one_error(runner.invoke(app, ["identify", str(bad), "--params", "kp"]))


def test_a_finite_copy_of_the_record_is_identified(excited, tmp_path):
    """The copy itself is a record identify reads: only the bad value is refused."""
    same = with_value(excited, tmp_path / "same", "qd_meas", "elbow", 0.125)
    result = runner.invoke(app, ["identify", str(same), "--params", "kp"])
    assert result.exit_code == 0, result.output


def test_the_stretches_too_short_between_missing_currents_are_counted_too(excited, tmp_path):
    """One tick in 150 without elbow's current, over 1.5 s: the warning said 10 ticks left out, the fit went without
    every tick between them (no stretch of 200). Over the whole record, nothing is left to fit: the refusal says why
    (it said "record at full rate", of a record at full rate)."""
    whole = json.loads(runner.invoke(app, ["identify", str(excited), "--params", "kp", "--json"]).stdout)
    sparse = with_value(excited, tmp_path / "sparse", "current", "elbow", np.nan, ticks=10, every=150)
    out = json.loads(runner.invoke(app, ["identify", str(sparse), "--params", "kp", "--json"]).stdout)
    said = [w for w in out["warnings"] if "left out" in w]
    dropped = whole["samples"] - out["samples"]
    assert dropped > 1300 and said and said[0].startswith(f"{sparse}: {dropped} of {whole['samples']} ticks"), said
    assert "on 10 ticks from t_ns" in said[0]
    everywhere = with_value(excited, tmp_path / "everywhere", "current", "elbow", np.nan, ticks=100, every=150, start=0)
    line = one_error(runner.invoke(app, ["identify", str(everywhere), "--params", "kp"]))
    assert "no stretch of 200 ticks at the servo rate; " in line and "no motor current (NaN) on elbow" in line, line


@pytest.mark.parametrize(("field", "joint", "value", "says"), [
    ("q_meas", "elbow", 3e38, "beyond its range [-2.5, 2.5] rad by 10 times its width"),
    ("q_cmd", "elbow", -1000.0, "beyond its range [-2.5, 2.5] rad by 10 times its width"),
    ("current", "elbow", 1e6, "a torque beyond 100 times its effort limit of"),
])
def test_a_position_setpoint_or_current_beyond_any_the_joint_reads_is_refused(excited, profile, tmp_path, field,
                                                                              joint, value, says):
    """A position of 3e38 rad was fitted (kp -4.7e-41, written, exit 0); a current of 1e6 A flooded the terminal
    with a million lines of MuJoCo warnings before a false "the records move too little"."""
    bad = with_value(excited, tmp_path / "bad", field, joint, value)
    before = files(profile.parent)
    line = one_error(runner.invoke(app, ["identify", str(bad), "--write", str(profile)]))
    assert f"({field}) of {joint} is {np.float32(value):g} " in line and f" at tick t_ns {T_NS}, {says}" in line, line
    assert files(profile.parent) == before


def test_a_current_the_fit_does_not_read_is_not_refused(excited, tmp_path):
    """The gripper is not fitted: its current at +inf on one tick refused the whole record."""
    odd = with_value(excited, tmp_path / "odd", "current", "gripper", np.inf)
    result = runner.invoke(app, ["identify", str(odd), "--params", "kp"])
    assert result.exit_code == 0, result.output
