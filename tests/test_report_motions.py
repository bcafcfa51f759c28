"""The report of a cell of several motions (the quadruped's left and right turns): each motion's drift values against
its own baseline band, and the last good cycle overlaid is of the first faulted one's motion."""

from __future__ import annotations

import pytest
import yaml
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.diagnose.from_record import diagnose_record
from cellguard.report import plots
from cellguard.report.from_record import write_report

runner = CliRunner()
LEFT_LEGS = ["fl_abduction", "fl_hip", "fl_knee", "rl_abduction", "rl_hip", "rl_knee"]


@pytest.fixture(scope="module")
def turns(tmp_path_factory):
    """Five left and five right turns of acceptance, then the left legs weak from cycle 12 (a left turn, after a
    right one): the diagnosis's last good cycle, 11, is of the other motion."""
    folder = tmp_path_factory.mktemp("motions")
    scenario = folder / "quad.yaml"
    scenario.write_text(yaml.safe_dump({
        "cell": "quadruped-turns", "seed": 7, "acceptance_cycles": 10, "production_cycles": 5,
        "faults": [{"kind": "servo_gain", "joint": LEFT_LEGS, "factor": 0.8, "at_cycle": 12}]}))
    result = runner.invoke(app, ["run", str(scenario), "--out", str(folder / "quad")])
    assert result.exit_code == 0, result.output
    d = diagnose_record(folder / "quad")
    assert len(d.baseline.motions) == 2 and d.first_faulted_cycle == 12 and d.last_good_cycle == 11
    return folder / "quad", d


def test_every_acceptance_cycle_lies_in_its_motions_band(turns):
    _, d = turns
    fig = plots.drift_figure(d)
    acceptance = {c.index for c in d.cycles if c.phase == "acceptance"}
    charts = [ax for ax in fig.axes if ax.get_title(loc="left") in d.baseline.names]
    assert charts
    outside = [(ax.get_title(loc="left"), int(x), f"{y:.4g} not in {low:.4g}..{high:.4g}")
               for ax in charts for band, line in zip(ax.patches, ax.lines)  # drawn in pairs: a band, its values
               for low, high in [(band.get_y(), band.get_y() + band.get_height())]
               for x, y in zip(*line.get_data()) if x in acceptance and not low <= y <= high]
    assert not outside, f"acceptance cycles outside their band: {outside[:4]}"
    assert all(len(ax.patches) == len(ax.lines) == 2 for ax in charts)
    labels = [line.get_label() for line in charts[0].lines]
    assert [label.split(":")[0] for label in labels] == list(d.baseline.motions)  # the legend names each motion


def test_the_overlay_is_of_the_first_faulted_cycles_motion(turns, tmp_path):
    run, d = turns
    bad = next(c for c in d.cycles if c.index == d.first_faulted_cycle)
    same = max(c.index for c in d.cycles if c.label == bad.label and c.index < bad.index and c.success)
    assert same != d.last_good_cycle  # the case: the last good cycle of all is the other turn
    page = write_report(run, tmp_path / "report.html").read_text()
    overlay = page[page.index('id="plot-overlay"'):page.index("</figure>", page.index('id="plot-overlay"'))]
    assert f"<!-- cycle {same} (last good, {bad.label}) -->" in overlay
    assert f"<!-- cycle {bad.index} (first faulted, {bad.label}) -->" in overlay
    assert f"cycle {d.last_good_cycle} (last good" not in overlay
    latest = max(c.index for c in d.cycles if c.label == bad.label)
    assert f"<!-- cycle {latest} (latest, {bad.label}) -->" in overlay
