"""identify refuses a record whose measured velocity is NaN or infinite at some tick, in one line naming the record,
the joint and the tick's time (one NaN of elbow's qd_meas, written with the mcap writer, made the least-squares solve
fail in a traceback: "SVD did not converge"); ``--write`` writes nothing."""

from __future__ import annotations

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


def with_velocity(source: Path, target: Path, joint: str, value: float) -> Path:
    """A copy of the record in folder ``source`` whose ``joint``'s measured velocity at ``T_NS`` is ``value``, in
    every tick stream that carries that tick, written through the mcap Writer (a record from another writer)."""
    edited = []

    def velocity(topic: str, data: bytes) -> bytes:
        if not topic.startswith("/ticks"):
            return data
        batch = TICKS.decode(data)
        hit = np.flatnonzero(np.asarray(batch["t_ns"]) == T_NS)
        if not len(hit):
            return data
        qd = np.array(batch["qd_meas"], dtype=np.float32).reshape(len(batch["t_ns"]), -1)
        qd[hit[0], list(batch["joints"]).index(joint)] = value
        edited.append(topic)
        return TICKS.encode(batch | {"qd_meas": qd.ravel()})

    rewrite(source, target, edit_bytes=velocity)
    assert edited, "no tick stream carries the tick"
    return target


def files(folder: Path) -> list[tuple[str, bytes]]:
    return sorted((p.name, p.read_bytes()) for p in folder.iterdir() if p.is_file())


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_a_velocity_that_is_not_finite_is_refused_naming_record_joint_and_tick(excited, profile, tmp_path,
                                                                                value):
    bad = with_velocity(excited, tmp_path / "bad", "elbow", value)
    before = files(profile.parent)
    line = one_error(runner.invoke(app, ["identify", str(bad), "--write", str(profile)]))
    assert line.startswith(f"error: {bad}: run ") and "measured velocity (qd_meas) of elbow is " in line, line
    assert f"is {value} at tick t_ns {T_NS} (1 of " in line, line
    assert files(profile.parent) == before  # nothing written
    # without --write as well: a fit of the drives alone read every joint's velocity
    assert "of elbow is" in one_error(runner.invoke(app, ["identify", str(bad), "--params", "kp"]))


def test_a_finite_copy_of_the_record_is_identified(excited, tmp_path):
    """The copy itself is a record identify reads: only the bad value is refused."""
    same = with_velocity(excited, tmp_path / "same", "elbow", 0.125)
    result = runner.invoke(app, ["identify", str(same), "--params", "kp"])
    assert result.exit_code == 0, result.output
