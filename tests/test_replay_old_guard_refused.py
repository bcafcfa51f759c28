"""``replay`` of a record whose guard settings this cellguard refuses (recorded before a check was added: a box in
millimetres beyond 100 m, one in centimetres over 10 times the arm's reach, a soft_margin leaving out the home pose)
is one line naming the record and the setting, exit 2, no page. The millimetre box ended in pydantic's
ValidationError traceback, exit 1. Such records cannot be made any more: the older record is this run's record with
its context's guard settings as the older cellguard wrote them."""

from __future__ import annotations

from dataclasses import replace

import pytest
from typer.testing import CliRunner

from cellguard.calibrate import replay as replay_module
from cellguard.cli import app
from cellguard.runtime.loop import run_scenario
from cellguard.scenario import Scenario

runner = CliRunner()


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    run = tmp_path_factory.mktemp("old_guard") / "run"
    run_scenario(Scenario(cell="arm-pick-place", acceptance_cycles=1, production_cycles=0), run)
    return run


def _replay(record, tmp_path):
    page = tmp_path / "page.html"
    return runner.invoke(app, ["replay", str(record), "--cycle", "0", "-o", str(page)]), page


@pytest.mark.parametrize(("guard", "says"), [
    ({"box": [[-300.0, -300.0, 0.0], [300.0, 300.0, 500.0]]},
     "guard.box: Value error, [[-300.0, -300.0, 0.0], [300.0, 300.0, 500.0]] reaches beyond 100 m"),
    ({"box": [[-45.0, -45.0, 0.5], [45.0, 45.0, 55.0]]},
     "guard.box: [[-45.0, -45.0, 0.5], [45.0, 45.0, 55.0]] m: z up to 55 m lies 54.24 m beyond where the tool"),
    ({"soft_margin": 0.2}, "guard.soft_margin: 0.2 puts the soft limits of elbow at [-1.5, 1.5] rad"),
])
def test_a_guard_this_cellguard_refuses_is_one_line_naming_the_record(record, tmp_path, monkeypatch, guard, says):
    load = replay_module.load_cycle

    def older(path, cycle):
        rc = load(path, cycle)
        return replace(rc, guard={**rc.guard, **guard})

    monkeypatch.setattr(replay_module, "load_cycle", older)
    result, page = _replay(record, tmp_path)
    assert result.exit_code == 2 and result.stderr.count("\n") == 1, result.output
    assert result.stderr.startswith(f"error: {record}: the record's guard settings, refused by this cellguard "
                                    "(replay cannot build the guard that ran): "), result.stderr
    assert says in result.stderr and "Traceback" not in result.output, result.stderr
    assert not page.exists()


def test_the_records_own_guard_replays(record, tmp_path):
    result, page = _replay(record, tmp_path)
    assert result.exit_code == 0, result.output
    assert page.is_file()
