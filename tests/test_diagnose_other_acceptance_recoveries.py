"""``diagnose RUN --acceptance OTHER`` takes every reference from OTHER's acceptance, the recoveries' too, and names
the cycles it watches by their phase.

The recovery reference (when the acceptance attempts of each behaviour and trigger arrived at contact, and how often
they picked the part again) came from RUN's own acceptance attempts while the baseline came from OTHER's: a run
whose recoveries were slow from its first cycle on was read against its own slow acceptance, and no recovery was
named. And RUN's acceptance cycles, watched against OTHER's acceptance, were called production cycles in the note
on cycles that carried no part.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from record_synth import DT_NS, JOINTS, context, tick
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.record.writer import Recorder
from cellguard.robot.recovery.outcome import RecoveryOutcome

ACCEPTANCE, PRODUCTION = 5, 5


def _record(folder, arrival_s: float, empty: set[int] = frozenset()) -> None:
    """5 acceptance and 5 production cycles, a retry of the grasp in each from cycle 1 on that arrives at contact
    ``arrival_s`` after it starts (the gripper shut at 3 s) and picks the part; ``empty`` cycles carried no part."""
    rng = np.random.default_rng(len(str(folder)))
    rec = Recorder.create(folder, joints=JOINTS, dt_ns=DT_NS, context=context(), epoch_wall_ns=1_790_000_000 * 10**9)
    k = 0
    for c in range(ACCEPTANCE + PRODUCTION):
        phase = "acceptance" if c < ACCEPTANCE else "production"
        rec.cycle_begin(c, phase, k * DT_NS)
        for _ in range(3):
            tick(rec, k, c)
            k += 1
        attempts = [RecoveryOutcome("retry_grasp", "grasp_missed", 1, "resumed", 4.0, arrival_s, 3.0)] if c else []
        features = {"current_rms.elbow": 0.4 + 0.001 * rng.standard_normal(), "grasped": float(c not in empty),
                    "recoveries": float(len(attempts))}
        rec.cycle_end({"cycle": c, "phase": phase, "success": True, "features": features,
                       "recovery_log": [a.to_dict() for a in attempts]}, k * DT_NS)
    rec.close()


@pytest.fixture(scope="module")
def records(tmp_path_factory):
    folder = tmp_path_factory.mktemp("records")
    _record(folder / "other", arrival_s=0.5)  # its recoveries at their plan's pace
    _record(folder / "run", arrival_s=2.0, empty={1, 7})  # slow from its first cycle on, acceptance too
    return folder / "run", folder / "other"


def _diagnosis(*args) -> dict:
    result = CliRunner().invoke(app, ["diagnose", *map(str, args), "--json"])
    assert result.exit_code in (0, 1), result.output
    return json.loads(result.output)


def test_recoveries_are_judged_against_the_other_records_acceptance_attempts(records):
    run, other = records
    assert [f["cause"] for f in _diagnosis(run)["findings"]] == []  # as slow as its own acceptance
    found = [f for f in _diagnosis(run, "--acceptance", other)["findings"] if f["cause"] == "recovery"]
    assert [f["cycle"] for f in found] == [1], found  # watched from its first cycle on, as the drift monitors
    assert found[0]["evidence"][:2] == [
        "9 recovery attempts from cycle 1 on arrived at contact 2.00 s after they started (median) vs 0.50 s for the "
        "4 acceptance recoveries (retry_grasp after grasp_missed)",
        "they picked the part again in 9 of 9 cycles vs 4 of 4 at acceptance"]


def test_the_note_on_cycles_of_another_load_names_acceptance_cycles_so(records):
    run, other = records
    own = CliRunner().invoke(app, ["diagnose", str(run)])
    assert "unwatched on 1 production cycle(s)" in " ".join(own.output.split()), own.output
    against = CliRunner().invoke(app, ["diagnose", str(run), "--acceptance", str(other)])
    said = " ".join(against.output.split())
    assert "unwatched on 1 acceptance and 1 production cycle(s)" in said and "(cycles 1, 7)" in said, said
