"""A metric's value that is no finite number, or a metric that raises or returns no Measure: one clear gate result
(a NaN compared false with every limit and passed every gate, hard ones included; a raise was a traceback that
left the stage's counted runs without their gates entry)."""

from __future__ import annotations

import json

import pytest
from release_helpers import CELL, cli, two_runs_at_sim, write_plan

from cellguard.release import Store, log
from cellguard.release.gates import Gate, evaluate
from cellguard.release.metrics import METRICS, Measure, Metric


def _metric(monkeypatch, name: str, compute, hard: bool = False) -> None:
    """``name`` registered as a gate metric; ``compute`` gets the runs given to ``evaluate``."""
    monkeypatch.setitem(METRICS, name, Metric(name, "", compute, hard=hard))


def _value(runs) -> Measure:
    """The runs here are the values themselves: the metric's figure is the first."""
    return Measure(runs[0], 5)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), "0", True])
def test_a_value_that_is_no_finite_number_fails_a_hard_gate_and_passes_no_other(monkeypatch, value):
    _metric(monkeypatch, "stops_count", _value, hard=True)
    _metric(monkeypatch, "rate", _value)
    hard = evaluate(Gate(metric="stops_count", max=0), [value])
    soft = evaluate(Gate(metric="rate", min=0.5, max=1.0), [value])
    assert (hard.status, soft.status) == ("fail", "inconclusive")
    for result in (hard, soft):
        assert result.detail == f"{result.metric} measured {value!r}, not a finite number"
        assert result.value is None  # logged and printed as no figure (a NaN is no JSON)


def test_last_goods_figure_that_is_no_number_passes_no_relative_gate(monkeypatch):
    _metric(monkeypatch, "rate", _value)
    result = evaluate(Gate(metric="rate", max_vs_last_good=1.05), [0.5], [float("nan")])
    assert result.status == "inconclusive" and "last_good's runs: rate measured nan" in result.detail
    assert evaluate(Gate(metric="rate", max_vs_last_good=1.05), [0.5], [0.5]).status == "pass"


def test_a_relative_gate_says_truly_why_it_has_no_last_good_figure(monkeypatch):
    """It said "no last_good on this stage" whatever the reason: where last_good had only runs made otherwise, or
    runs with no figure."""
    _metric(monkeypatch, "rate", _value)
    gate = Gate(metric="rate", max=1.0, max_vs_last_good=1.05)
    assert evaluate(gate, [0.5]).detail == "0.5  (no last_good on this stage: absolute limit only)"
    why = "last_good abc has no runs of this stage's runs"
    assert evaluate(gate, [0.5], [], why).detail == f"0.5  ({why}: absolute limit only)"
    assert evaluate(gate, [0.5], [None], why).detail == "0.5  (no figure in last_good's runs: absolute limit only)"
    alone = evaluate(Gate(metric="rate", max_vs_last_good=1.05), [0.5], [], why)
    assert (alone.status, alone.detail) == ("inconclusive", f"{why}: nothing to compare with")


def _raises(runs):
    raise RuntimeError("the plugin's own bug")


@pytest.mark.parametrize(("compute", "words"), [(_raises, "raised RuntimeError: the plugin's own bug"),
                                                (lambda runs: 0.0, "returned 0.0, not a Measure"),
                                                (lambda runs: Measure(0.0, "5"), "cycles are no count")])
def test_a_metric_that_raises_or_returns_no_measure_is_one_result_naming_it(monkeypatch, compute, words):
    _metric(monkeypatch, "plugin_rate", compute)
    _metric(monkeypatch, "plugin_stops", compute, hard=True)
    soft = evaluate(Gate(metric="plugin_rate", max=1), [0.5])
    hard = evaluate(Gate(metric="plugin_stops", max=0), [0.5])
    assert (soft.status, hard.status) == ("inconclusive", "fail")
    assert soft.detail.startswith("plugin_rate ") and words in soft.detail


def test_release_run_logs_the_gates_of_a_metric_that_raises(tmp_path, monkeypatch):
    """`release run` ended in a traceback: its runs counted, no gates entry logged."""
    _metric(monkeypatch, "plugin_rate", _raises)
    _, site, rid = two_runs_at_sim(tmp_path, 1)
    plan = write_plan(tmp_path / "plugin.yaml", {"sim": {"runs": [{"name": "one", "seed": 5, "acceptance_cycles": 1}],
                                                         "gates": [{"metric": "success_rate", "min": 0},
                                                                   {"metric": "plugin_rate", "max": 1}]}})
    result = cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(plan), "--site", str(site), "--json")
    assert result.exit_code == 1 and isinstance(result.exception, SystemExit), result.output
    gates = {g["metric"]: g for g in json.loads(result.stdout)["gates"]}
    assert gates["plugin_rate"]["status"] == "inconclusive" and "RuntimeError" in gates["plugin_rate"]["detail"]
    entry = log.entries(Store(site))[-1].body
    assert (entry["kind"], entry["release"], entry["verdict"]) == ("gates", rid, "inconclusive")
    assert len(entry["runs"]) == 1
