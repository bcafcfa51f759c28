"""Process changes: parsed from scenarios, simulated in the cells, declared in the record's context."""

from __future__ import annotations

import numpy as np
import pytest

from cellguard.errors import ScenarioError
from cellguard.robot.arm_cell import ArmPickPlace
from cellguard.robot.process import PROCESS_CHANGES
from cellguard.robot.quadruped_cell import QuadrupedTurns
from cellguard.scenario import parse_scenario

PAYLOAD = {"kind": "payload", "at_cycle": 3, "grams": 40.0}
WARMUP = {"kind": "warmup", "at_cycle": 2, "idle_min": 90, "friction": 0.5, "cycles": 4}


def _scenario(changes, cell="arm-pick-place"):
    return parse_scenario({"cell": cell, "process_changes": changes})


def test_registry_and_parsing():
    assert set(PROCESS_CHANGES) == {"payload", "warmup"}
    s = _scenario([PAYLOAD, {**WARMUP, "declared": False}])
    assert [c.kind for c in s.process_changes] == ["payload", "warmup"]
    with pytest.raises(ScenarioError, match=r"process_changes\[0\]: unknown process change kind"):
        _scenario([{"kind": "new_batch", "at_cycle": 1}])
    with pytest.raises(ScenarioError, match=r"process_changes\[0\]\.grams"):
        _scenario([{**PAYLOAD, "grams": 1e6}])
    with pytest.raises(ScenarioError, match=r"process_changes\[0\]\.speed: unknown key"):
        _scenario([{**PAYLOAD, "speed": 1}])


def test_a_cell_that_cannot_simulate_a_change_refuses_it():
    s = _scenario([PAYLOAD], cell="quadruped-turns")
    with pytest.raises(ScenarioError, match=r"process_changes\[0\]\.kind: 'payload' cannot be simulated"):
        s.check_against(QuadrupedTurns())


def test_payload_makes_the_part_heavier_from_its_cycle():
    cell, change = ArmPickPlace(), _scenario([PAYLOAD]).process_changes[0]
    body = cell._part_body
    change.apply(cell, 2)
    assert cell.model.body_mass[body] == pytest.approx(0.05)
    change.apply(cell, 3)
    assert cell.model.body_mass[body] == pytest.approx(0.09)


def test_warmup_friction_decays_on_every_joint():
    cell, change = ArmPickPlace(), _scenario([WARMUP]).process_changes[0]
    nominal = cell.drives.nominal_frictionloss
    factors = []
    for cycle in (1, 2, 6, 30):
        change.apply(cell, cycle)
        factors.append(cell.model.dof_frictionloss[cell.drives.dadr] / np.where(nominal > 0, nominal, 1.0))
    assert np.allclose(factors[1][nominal > 0], 1.5) and np.allclose(factors[2][nominal > 0], 1 + 0.5 / np.e)
    assert np.allclose(factors[3][nominal > 0], 1.0, atol=1e-3)


def test_only_declared_changes_that_happened_are_in_the_record_context():
    s = _scenario([PAYLOAD, {**WARMUP, "declared": False}])
    assert s.declared_process(2) == []
    assert s.declared_process(3) == [{"kind": "payload", "at_cycle": 3, "grams": 40.0}]
    assert s.declared_process(99) == s.declared_process(3)  # the undeclared warm-up never appears
