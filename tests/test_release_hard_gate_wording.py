"""A gate the plan marks `hard: true` with another limit than `max: 0` is refused naming the plan's `hard: true`:
`{metric: success_rate, min: 1.0, hard: true}` was told "success_rate is a hard gate", as if the metric were."""

from __future__ import annotations

import pytest
from release_helpers import ONE, write_plan

from cellguard.release import load_plan
from cellguard.release.errors import GateError


@pytest.mark.parametrize(("gate", "said"), [
    ({"metric": "success_rate", "min": 1.0, "hard": True},
     "gates[0]: hard: true makes success_rate a hard gate, which fails on any value above 0: its only limit is max: "
     "0; for another limit leave out hard: true"),
    ({"metric": "protective_stops", "max": 1},  # hard by the metric: said so
     "gates[0]: protective_stops is a hard gate: its failure limit is 0, write max: 0"),
])
def test_a_hard_gate_with_another_limit_says_what_made_it_hard(tmp_path, gate, said):
    plan = write_plan(tmp_path / "plan.yaml", {"sim": {"runs": [ONE], "gates": [gate]}})
    with pytest.raises(GateError) as refused:
        load_plan(plan)
    assert str(refused.value).endswith(said)
