"""The report and the diagnosis JSON can be dated and traced on their own: the run's UTC start, its record id
and profile version in the page's header and in ``diagnose --json``'s ``record``; the guard events with their
joint and asked/sent values; charts that carry no date of their own (an older record says "unknown")."""

from __future__ import annotations

import html
import json
import re

import pytest
import yaml
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.diagnose import diagnose
from cellguard.report import render_report
from cli_util import record_run

runner = CliRunner()
START = "2026-11-26T18:13:27.383+00:00"
CONTEXT = {"cell": "arm-pick-place", "record_id": "c51dd21de5c54f239e3f186feac97028", "start_utc": START,
           "embodiment": {"robot": "so101", "version": "1.4.0"}}
LIMIT = {"t_ns": 100_000_000_000, "kind": "limit_intervention", "reason": "reference outside the envelope",
         "joint": "shoulder_lift", "asked": -0.28483693994510495, "sent": -0.2848371280155815}
STOP = {"t_ns": 140_000_000_000, "kind": "watchdog_stop", "reason": "policy silent", "category": 2}


def _rows():
    out = []
    for i in range(40):
        f = {"current_rms.elbow": 0.41 + 0.001 * (i % 3) + (0.05 if i >= 30 else 0.0), "tracking_rms.elbow": 0.0133,
             "cycle_time_s": 4.444}
        out.append({"cycle": i, "phase": "acceptance" if i < 20 else "production", "success": True, "features": f})
    return out


def _header(page: str) -> str:
    return re.search(r"<p id=run>.*?</p>", page).group(0)


def test_the_header_dates_the_run_and_names_its_record():
    d = diagnose(_rows(), [LIMIT, STOP], CONTEXT)
    header = _header(render_report(d))
    assert START in header and CONTEXT["record_id"] in header and "1.4.0" in header
    assert d.to_dict()["record"] == {"record_id": CONTEXT["record_id"], "start_utc": START,
                                     "profile_version": "1.4.0"}


@pytest.mark.parametrize("context", [{}, {"cell": "arm-pick-place", "embodiment": "so101"}])
def test_an_older_record_without_them_reports_unknown(context):
    d = diagnose(_rows(), [STOP], context)
    assert _header(render_report(d)).count("unknown") == 3
    assert d.to_dict()["record"] == {"record_id": None, "start_utc": None, "profile_version": None}


def test_guard_events_show_their_joint_and_asked_and_sent_values():
    d = diagnose(_rows(), [LIMIT, STOP], CONTEXT)
    page = render_report(d)
    table = page[page.index("<h2>Guard events</h2>"):page.index("<h2>Context</h2>")]
    assert "<th>joint</th><th>asked</th><th>sent</th>" in table
    assert "<td>limit_intervention</td><td>shoulder_lift</td><td>-0.28483694</td><td>-0.284837128</td>" in table
    assert "<td>watchdog_stop</td><td></td><td></td><td></td><td>2</td>" in table  # none: empty, not "None"
    limit = next(e for e in d.to_dict()["safety_events"] if e["kind"] == "limit_intervention")
    assert (limit["joint"], limit["asked"], limit["sent"]) == ("shoulder_lift", LIMIT["asked"], LIMIT["sent"])


def test_a_long_context_entry_is_folded_whole_and_a_short_one_is_inline():
    """The profile's whole document (2.4 KB of JSON) filled the context table as one line."""
    document = {"robot": "so101", "joints": [{"name": f"joint_{i}", "velocity": 1.5 + i} for i in range(40)]}
    d = diagnose(_rows(), [STOP], {**CONTEXT, "embodiment": {"version": "1.4.0", "document": document}})
    table = render_report(d).split("<h2>Context</h2>", 1)[1]
    folded = re.search(r"<tr><th>embodiment</th><td><details><summary>version, document</summary><pre>(.*?)</pre>",
                       table, re.S)
    assert folded and json.loads(html.unescape(folded.group(1)))["document"] == document
    assert "<tr><th>cell</th><td><code>arm-pick-place</code></td></tr>" in table


def test_events_of_a_run_on_wall_time_are_timed_from_its_start():
    """On hardware the run clock counts from the host's boot: the events read 61234.5 s into a 3-minute run."""
    boot = 61_234_000_000_000
    stop = {**STOP, "t_ns": boot + 1_500_000_000}
    page = render_report(diagnose(_rows(), [stop], {**CONTEXT, "start_ns": boot}))
    table = page[page.index("<h2>Guard events</h2>"):page.index("<h2>Context</h2>")]
    assert "<th>t [s] from start</th>" in table and "<tr><td>1.500</td>" in table


def test_a_gait_asymmetry_names_the_measures_that_differ():
    from cellguard.diagnose.asymmetry import Asymmetry, MirrorDifference

    d = MirrorDifference("step_period_s.rl", "step_period_s.rl during left turns", "step_period_s.rr during right turns",
                         1.45, 0.73, 0.66, 130.0, "step_period_s.rr", ("left", "right"))
    assert Asymmetry("right", (), (d,), ()).what == ("step_period_s",)
    assert Asymmetry("right", ("rr_knee",), (d,), ()).what == ("rr_knee",)


def test_the_charts_carry_no_date_and_the_page_draws_the_same_twice():
    d = diagnose(_rows(), [STOP], CONTEXT)
    page = render_report(d)
    assert "<svg" in page and "<dc:date>" not in page
    assert render_report(d) == page


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    return record_run(tmp_path_factory.mktemp("dated"))


def test_a_recorded_run_is_dated_as_record_info_dates_it(recorded, tmp_path):
    info = json.loads(runner.invoke(app, ["record", "info", str(recorded), "--json"]).stdout)
    assert info["start_utc"].endswith("+00:00") and info["record_id"]
    out = json.loads(runner.invoke(app, ["diagnose", str(recorded), "--no-fleet", "--json"]).stdout)["record"]
    assert out["ok"] is True and out["record_id"] == info["record_id"] and out["start_utc"] == info["start_utc"]
    assert out["profile_version"] == info["context"]["embodiment"]["version"]
    result = runner.invoke(app, ["report", str(recorded), "--no-fleet", "-o", str(tmp_path / "r.html")])
    assert result.exit_code == 0, result.output
    header = _header((tmp_path / "r.html").read_text())
    assert info["start_utc"] in header and info["record_id"] in header
