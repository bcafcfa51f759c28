"""Diagnosis findings from a hostile probe (P1), each on a real record: a run that ended in a stop was "no fault
found", exit 0; a fault present from the first cycle recorded had a "last good cycle" that held it; a cycle cut
short by SIGTERM raised a drift alarm on its own."""

from __future__ import annotations

import json
import re
import signal
from collections.abc import Callable
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.diagnose.diagnosis import diagnose
from cellguard.record.reader import open_record
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import parse_scenario

runner = CliRunner()
LATE = {"cell": "arm-pick-place", "seed": 17, "policy": "scripted", "acceptance_cycles": 8, "production_cycles": 8,
        "faults": [{"kind": "policy_latency", "at_cycle": 10, "ms": 600, "until_cycle": 12}]}
WEAK_FROM_START = {"cell": "quadruped-turns", "seed": 9, "policy": "scripted", "policy_hz": 20,
                   "acceptance_cycles": 10, "production_cycles": 6,
                   "faults": [{"kind": "servo_gain", "factor": 0.8, "at_cycle": 0,
                               "joint": ["fl_abduction", "fl_hip", "fl_knee", "rl_abduction", "rl_hip", "rl_knee"]}]}
FROM_START = ("present from the first cycle recorded: no good cycle in this record; diagnose against another "
              "record's acceptance")
HEALTHY = {"cell": "arm-pick-place", "seed": 61, "policy": "scripted", "acceptance_cycles": 8, "production_cycles": 8}


def _sigterm_at(run: Run, cycle: int, tick: int) -> Callable[[dict], None]:
    """SIGTERM to this process on servo write ``tick`` of cycle ``cycle``: an operator's stop mid-cycle, at the same
    simulated instant on every machine. Returns the ``on_cycle`` that counts the cycles finished."""
    finished, writes, write = [0], [0], run.cell.write

    def counted(setpoint):
        writes[0] += finished[0] == cycle
        if finished[0] == cycle and writes[0] == tick:
            signal.raise_signal(signal.SIGTERM)
        return write(setpoint)

    run.cell.write = counted
    return lambda _: finished.__setitem__(0, finished[0] + 1)


@pytest.fixture(scope="module")
def records(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("probe")
    out = {name: root / name for name in ("late", "from_start", "cut")}
    run_scenario(parse_scenario(LATE), out["late"])  # the policy is lost in cycle 10: the run ends stopped
    run_scenario(parse_scenario(WEAK_FROM_START), out["from_start"])
    scenario = parse_scenario(HEALTHY)
    run = Run(scenario)
    on_cycle = _sigterm_at(run, 15, 2260)  # 2.26 s into the last production cycle, as the probe's SIGTERM came
    run_scenario(scenario, out["cut"], on_cycle=on_cycle, run=run)
    return out


def _diagnosed(folder: Path) -> tuple[dict, str, int, str]:
    """(the JSON, the text, the text's exit code, the report's findings section as text) of ``folder``."""
    as_json = runner.invoke(app, ["diagnose", str(folder), "--json"])
    text = runner.invoke(app, ["diagnose", str(folder)])
    report = runner.invoke(app, ["report", str(folder)])
    assert as_json.exit_code == text.exit_code == report.exit_code, (text.output, report.output)
    page = (folder / "report.html").read_text()
    findings = re.sub(r"<[^>]+>", " ", page[page.index("<h2>Findings"):page.index("<h2>Drift")])
    return json.loads(as_json.stdout), " ".join(text.output.split()), text.exit_code, " ".join(findings.split())


def test_a_run_ended_by_a_lost_policy_is_diagnosed_as_its_latency_from_the_stale_chunks(records):
    data, text, code, page = _diagnosed(records["late"])
    assert [(f["cause"], f["cycle"]) for f in data["findings"]] == [("policy_latency", 10)], data["findings"]
    assert data["run_end"]["kind"] == "policy_lost" and data["run_end"]["cycle"] == 10
    evidence = " ".join(data["findings"][0]["evidence"])
    assert "610 ms per chunk in cycle 10 vs 10 ms at acceptance" in evidence and "2 chunk(s) came stale" in evidence
    assert (data["last_good_cycle"], data["first_faulted_cycle"]) == (9, 10)
    assert "the run ended: policy_lost in cycle 10, category 2" in text and "no fault found" not in text
    assert code == 0, text  # a finding explains it
    assert "policy_latency from cycle 10" in page and "No drift, fault" not in page
    assert "The run ended: policy_lost in cycle 10, category 2" in page


def test_a_stop_no_finding_explains_is_never_no_fault_found_with_exit_0(records, capsys):
    """The same record with the latency and the stale chunks taken out of it: the stop is still there."""
    from cellguard.cli.diagnose import warn_of_diagnosis

    with open_record(records["late"]) as rec:
        rows, events, context = list(rec.cycles()), list(rec.events()), dict(rec.context)
    rows = [r if r.cycle != 10 else {"cycle": 10, "phase": r.phase, "success": False,
                                     "features": {**r.features, "latency_mean_ms": 10.0, "latency_max_ms": 10.0}}
            for r in rows]
    events = [e for e in events if e.kind not in ("chunk_stale", "watchdog_stop")]
    d = diagnose(rows, events, context)
    assert d.findings == () and d.run_end is not None and d.run_end.kind == "policy_lost"
    assert warn_of_diagnosis(d) == 1
    assert "warning: the run ended in a stop no finding explains (policy_lost in cycle 10, category 2" in \
        " ".join(capsys.readouterr().err.split())


def test_a_fault_present_from_the_first_cycle_recorded_has_no_last_good_cycle(records):
    data, text, code, page = _diagnosed(records["from_start"])
    assert data["findings"][0]["cause"] == "servo" and data["findings"][0]["cycle"] == 10
    assert data["last_good_cycle"] is None and data["first_faulted_cycle"] == 10
    assert data["present_from_start"] == f"servo from cycle 10: {FROM_START}"
    assert "last good cycle" not in text and f"first faulted cycle 10 ({FROM_START})" in text
    assert code == 1 and "warning: baseline: servo from cycle 10: present from the first cycle recorded" in text
    page_all = (records["from_start"] / "report.html").read_text()
    assert "last good)" not in page_all and "Last good cycle <b>" not in page_all
    assert FROM_START.replace("'", "&#x27;") in page_all


def test_a_cycle_cut_short_by_sigterm_is_left_out_of_the_monitors(records):
    data, text, code, page = _diagnosed(records["cut"])
    assert data["drift_alarms"] == [] and data["findings"] == []  # the cut cycle alone alarmed the T^2 monitor
    assert data["run_end"]["kind"] == "operator_stop" and data["run_end"]["needs_cause"] is False
    assert data["cut_short_cycles"]["cycles"] == [15]
    assert "0 drift alarm(s)" in text and "note: cycle 15 cut short by the run's end" in text
    assert "no fault found" in text and code == 0  # the operator's stop is no fault of the cell
    assert "Cycle 15 cut short by the run" in page and "No drift, fault or asymmetry found" in page


def _lost_to(tmp_path: Path, answer, from_cycle: int) -> Path:
    """A run whose every answer from production cycle ``from_cycle`` on is ``answer(call, chunk)``'s (a NaN chunk, a
    failed call): the policy is lost in that cycle (8 acceptance cycles first)."""
    from test_runtime_rejected_answers import _Answers

    scenario = parse_scenario({**HEALTHY, "production_cycles": 4, "realtime": {"overrun_budget": 1_000_000}})
    cycle = [0]
    run = Run(scenario, policy_factory=lambda: _Answers(lambda call, chunk: answer(call, chunk)
                                                        if cycle[0] >= from_cycle else None))
    run_scenario(scenario, tmp_path / "run", run=run, on_cycle=lambda _: cycle.__setitem__(0, cycle[0] + 1))
    return tmp_path / "run"


def test_a_policy_lost_to_nan_chunks_or_failed_calls_is_not_named_latency(tmp_path):
    """Every loss after a first chunk has a watchdog stop in its cycle: read as lateness, a NaN in every chunk came
    out policy_latency first (confidence 0.9), and failing calls policy_latency alone."""
    from test_runtime_rejected_answers import _nan

    def failed(call, chunk):
        return RuntimeError("server error: connection reset")

    for name, answer in (("nan", _nan), ("failed", failed)):
        data, text, code, _ = _diagnosed(_lost_to(tmp_path / name, answer, 10))
        assert data["run_end"]["kind"] == "policy_lost" and data["run_end"]["cycle"] == 10, data["run_end"]
        causes = [f["cause"] for f in data["findings"]]
        assert "policy_latency" not in causes, (name, causes)
        assert causes == (["policy_output"] if name == "nan" else []), (name, causes)
        assert code == (0 if name == "nan" else 1)  # a stop no finding explains is a warning


def test_a_run_lost_in_its_first_production_cycle_is_still_diagnosed(tmp_path):
    """Its one production cycle, cut short, was left out: 'no production cycles', exit 2, and the run's findings
    were left out of the fleet's push."""
    from test_runtime_rejected_answers import _nan

    data, text, code, _ = _diagnosed(_lost_to(tmp_path, _nan, 8))
    assert [(f["cause"], f["cycle"]) for f in data["findings"]] == [("policy_output", 8)], data["findings"]
    assert code == 0 and data["cut_short_cycles"]["cycles"] == []


def test_a_stop_after_the_one_that_ended_the_run_does_not_hide_it(records):
    """A Ctrl-C during the retreat after a lost policy was taken as the run's end: the operator's, no cause to
    find, "no fault found"."""
    from cellguard.control.events import Event, EventKind

    with open_record(records["late"]) as rec:
        rows, events, context = list(rec.cycles()), list(rec.events()), dict(rec.context)
    later = max(e.t_ns for e in events) + 200_000_000
    d = diagnose(rows, [*events, Event(later, EventKind.OPERATOR_STOP, "SIGINT during the retreat", category=2)],
                 context)
    assert d.run_end.kind == "policy_lost" and [(f.cause, f.cycle) for f in d.findings] == [("policy_latency", 10)]
