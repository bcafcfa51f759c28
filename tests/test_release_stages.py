"""Stages and gates: out-of-order promotions and unknown metrics are refused; gates on real runs."""

from __future__ import annotations

import dataclasses

import pytest
from release_helpers import CELL, cli, pointers, replay_file, two_runs_at_sim, write_plan

from cellguard.control.checks.safety_input import ASKED_BY_LOOP, RECOVERY_HOLD
from cellguard.record.reader import EventRecord
from cellguard.release import Store, create_bundle, load_plan, promote, run_stage
from cellguard.release.errors import BundleMismatch, GateError
from cellguard.release.evidence import load_run
from cellguard.release.gates import Gate, evaluate
from cellguard.release.log import entries


def test_a_promotion_that_skips_a_stage_is_one_line_exit_2_and_moves_nothing(tmp_path):
    site = tmp_path / "site"
    store = Store(site)
    bundle = create_bundle("scripted", None, CELL, None)
    store.add_bundle(bundle)
    promote(store, bundle.id, CELL, "sim")
    before = pointers(site)
    for to in ("bench", "pilot", "production"):
        result = cli("promote", bundle.id, "--cell", CELL, "--to", to, "--site", str(site))
        assert result.exit_code == 2 and len(result.stderr.strip().splitlines()) == 1
        assert "entered only from the one before it" in result.stderr
    assert pointers(site) == before
    assert cli("promote", bundle.id, "--cell", CELL, "--to", "staging", "--site", str(site)).exit_code == 2


def test_a_gate_on_an_unknown_metric_is_one_line_exit_2(tmp_path):
    plan = write_plan(tmp_path / "plan.yaml", {"sim": {"runs": [{"name": "a"}],
                                                      "gates": [{"metric": "success_rate", "min": 1},
                                                                {"metric": "happiness", "min": 1}]}})
    with pytest.raises(GateError, match=r"stages.sim.gates\[1\]: unknown metric 'happiness'; known: "
                                        r"chunk_seam_jump_max_mrad, .*, success_rate$"):
        load_plan(plan)
    site = tmp_path / "site"
    store = Store(site)
    bundle = create_bundle("scripted", None, CELL, None)
    store.add_bundle(bundle)
    promote(store, bundle.id, CELL, "sim")
    before = pointers(site)
    result = cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(plan), "--site", str(site))
    assert result.exit_code == 2 and "unknown metric 'happiness'" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and pointers(site) == before


def test_a_hard_gate_with_a_failure_limit_above_zero_is_refused(tmp_path):
    plan = write_plan(tmp_path / "plan.yaml", {"sim": {"gates": [{"metric": "protective_stops", "max": 2}]}})
    with pytest.raises(GateError, match="failure limit is 0"):
        load_plan(plan)


@pytest.fixture(scope="module")
def one_run(tmp_path_factory):
    """One scripted cycle on the arm through the sim stage: a real record to evaluate gates on."""
    tmp = tmp_path_factory.mktemp("gates")
    plan = load_plan(write_plan(tmp / "plan.yaml", {"sim": {"runs": [{"name": "one", "seed": 2,
                                                                      "acceptance_cycles": 1}],
                                                            "gates": [{"metric": "success_rate", "min": 1.0}]}}))
    store = Store(tmp / "site")
    bundle = create_bundle("scripted", None, CELL, None)
    store.add_bundle(bundle)
    promote(store, bundle.id, CELL, "sim")
    result = run_stage(store, plan["sim"], CELL, "sim")
    return store, bundle, result


def test_gates_on_a_real_run_pass_fail_or_stay_inconclusive(one_run):
    store, bundle, result = one_run
    assert result.verdict == "pass" and store.pointers(CELL, "sim").last_good == bundle.id
    run = load_run(result.folders[0], "one")
    assert run.context["release"]["id"] == bundle.id and run.context["release"]["switch"]["kind"] == "promote"
    assert evaluate(Gate(metric="success_rate", min=1.0, min_cycles=2), [run]).status == "inconclusive"
    assert evaluate(Gate(metric="cycle_time_p95_s", max=1.0), [run]).status == "fail"
    assert evaluate(Gate(metric="cycle_time_p95_s", max_vs_last_good=1.05), [run]).status == "inconclusive"
    assert evaluate(Gate(metric="cycle_time_p95_s", max_vs_last_good=0.9), [run], [run]).status == "fail"
    assert evaluate(Gate(metric="protective_stops", max=0), [run]).status == "pass"
    assert evaluate(Gate(metric="shadow_distance_p95_mrad", max=1.0), [run]).status == "inconclusive"


def test_a_stop_the_loop_asked_for_counts_once(one_run):
    """The loop's own event and the guard's protective stop that carries it out are one stop; a stop asked
    with no event of the loop's (a recovery's hand-over hold) and the safety input's still count."""
    store, _, result = one_run
    run = load_run(result.folders[0], "one")

    def stops(*events):
        return evaluate(Gate(metric="protective_stops", max=0),
                        [dataclasses.replace(run, events=tuple(EventRecord(*e) for e in events))]).value

    operator = (10, "operator_stop", "SIGINT: the operator asked a stop", 2, None, None, None, 0)
    carried = (11, "protective_stop", ASKED_BY_LOOP + "operator stop (SIGINT)", 2, None, None, None, 0)
    hold = (50, "protective_stop", ASKED_BY_LOOP + RECOVERY_HOLD, 2, None, None, None, 1)
    controller = (60, "protective_stop", "safety controller protective stop input", 1, None, None, None, 1)
    assert stops(operator, carried) == 1
    assert stops(operator, carried, hold) == 2 and stops(hold, controller) == 2
    fault = (40, "robot_state_stale", "state stamp 30.0 ms old (limit 20 ms)", 2, None, None, None, 1)
    assert stops(fault, hold) == 2  # a later hold in the fault's cycle is a stop of its own (it was absorbed)


def test_promotion_needs_the_previous_stage_passed(one_run):
    store, bundle, _ = one_run
    promote(store, bundle.id, CELL, "bench")
    assert store.pointers(CELL, "bench").current == bundle.id and store.pointers(CELL, "bench").last_good is None
    with pytest.raises(Exception, match="no gate results at bench"):
        promote(store, bundle.id, CELL, "pilot")


def test_a_stage_run_whose_record_failed_is_not_counted_and_evaluates_no_gate(tmp_path, monkeypatch):
    """A full disk or a recorder fault is no evidence about the release (counted, its partial run could fail
    production's gates and roll a good release back)."""
    from cellguard.record.writer import Recorder

    plan, site, release = two_runs_at_sim(tmp_path, 2)
    flush, calls = Recorder._flush, {"n": 0}

    def failing_disk(self, *args):  # the writer process inherits it
        calls["n"] += 1
        if calls["n"] == 5:
            raise OSError(28, "No space left on device")
        flush(self, *args)

    monkeypatch.setattr(Recorder, "_flush", failing_disk)
    result = cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(plan), "--site", str(site))
    assert result.exit_code == 2, result.output
    line = result.stderr.strip().splitlines()[-1]
    assert line.startswith("error: the record of sim run 'first'") and "No space left on device" in line
    assert "not counted" in line and "gates were not evaluated" in line
    assert len(list((site / "runs" / CELL / "sim").iterdir())) == 1  # the second run never started
    assert Store(site).runs(CELL, "sim", release) == []
    assert [e.body["kind"] for e in entries(Store(site))] == ["promote"]  # no gates entry


@pytest.mark.parametrize("gate", [{"metric": "success_rate", "min": float("nan")},
                                  {"metric": "success_rate", "max": float("inf")},
                                  {"metric": "success_rate", "min": "0.5"},
                                  {"metric": "success_rate", "min": True},
                                  {"metric": "success_rate", "min": 0.5, "min_cycles": "1"},
                                  {"metric": "success_rate", "min": 0.5, "hard": "yes"}])
def test_a_gate_threshold_that_is_not_a_finite_number_is_refused(tmp_path, gate):
    """``min: .nan`` passed every value (``x >= nan`` is never false in the gate's test); strings were coerced."""
    with pytest.raises(GateError, match=r"stages.sim.gates\[0\]\."):
        load_plan(write_plan(tmp_path / "plan.yaml", {"sim": {"gates": [gate]}}))


def test_a_threshold_yaml_reads_as_text_says_so_and_an_exponent_without_a_dot_is_a_number(tmp_path):
    """``max: "1e3"`` is text, which the gate refuses, saying why; ``max: 1e3`` (YAML 1.1's text) is 1000."""
    plan = tmp_path / "plan.yaml"
    plan.write_text("stages:\n  sim:\n    gates:\n      - {metric: cycle_time_p95_s, max: \"1e3\"}\n")
    with pytest.raises(GateError, match=r"gates\[0\]\.max: .*got '1e3': text to YAML; write the number unquoted"):
        load_plan(plan)
    plan.write_text("stages:\n  sim:\n    gates:\n      - {metric: cycle_time_p95_s, max: 1e3}\n")
    assert load_plan(plan)["sim"].gates[0].max == 1000.0


def test_a_stage_flag_that_is_not_a_boolean_is_refused(tmp_path):
    with pytest.raises(GateError, match=r"stages.pilot.shadow"):
        load_plan(write_plan(tmp_path / "plan.yaml", {"pilot": {"shadow": "yes"}}))


@pytest.mark.parametrize("name", ["x/../../../escaped", "..", ".hidden", "a\x00b", "\x1b[31mred", "", "a" * 65,
                                  ["a"], 7])
def test_a_run_name_that_is_not_a_plain_folder_name_is_refused(tmp_path, name):
    """A run's folder is named after it: a path in the name wrote the record outside the site."""
    plan = write_plan(tmp_path / "plan.yaml", {"sim": {"runs": [{"name": name, "acceptance_cycles": 1}]}})
    with pytest.raises(GateError, match=r"stages.sim.runs\[0\].name: .* is not a run name"):
        load_plan(plan)


def test_a_policy_file_swapped_between_two_runs_of_a_stage_stops_the_stage(tmp_path):
    """The release is checked when the stage starts; the second run loaded another file: it must not run and
    count under the release's name (its gates passed, and the release went on to bench)."""
    policy = replay_file(tmp_path / "policy.npz")
    store = Store(tmp_path / "site")
    bundle = create_bundle(f"replay:{policy}", None, CELL, None)
    store.add_bundle(bundle)
    promote(store, bundle.id, CELL, "sim")
    runs = [{"name": name, "seed": 2, "acceptance_cycles": 1} for name in ("first", "second")]
    plan = load_plan(write_plan(tmp_path / "plan.yaml", {"sim": {"runs": runs,
                                                                "gates": [{"metric": "success_rate", "min": 0}]}}))

    def swap_before_the_second(line: str) -> None:
        if line.startswith("sim: second "):
            replay_file(policy, offset=0.05)

    with pytest.raises(BundleMismatch, match=r"policy .*policy.npz changed since create"):
        run_stage(store, plan["sim"], CELL, "sim", on_run=swap_before_the_second)
    assert [r.name for r in store.runs(CELL, "sim", bundle.id)] == ["first"]
    assert [e.body["kind"] for e in entries(store)] == ["promote"]  # no gates entry: nothing to promote on


@pytest.mark.parametrize("stage, says", [
    ({"gates": [{"metric": "success_rate", "min": 2.0}]}, r"gates\[0\]: min 2: success_rate is at most 1"),
    ({"gates": [{"metric": "success_rate", "min": 0.9, "max": 0.5}]}, r"gates\[0\]: the lower limit 0.9 is above"),
    ({"gates": [{"metric": "cycle_time_p95_s", "max_vs_last_good": 0.9, "min_vs_last_good": 1.1}]},
     r"gates\[0\]: the lower limit 1.1 is above the upper 0.9"),
    ({"gates": [{"metric": "shadow_would_clamp", "max": -0.1}]}, r"gates\[0\]: max -0.1: .* at least 0"),
    ({"gates": [{"metric": "success_rate", "min": 1.0, "min_cycles": 10**23}]},
     r"gates\[0\]\.min_cycles: Input should be less than or equal to 1000000"),
    ({"runs": [{"name": "a", "acceptance_cycles": 1}]}, r"stages.sim: runs but no gates"),
])
def test_a_gate_that_can_never_pass_is_refused_naming_the_stage_and_gate(tmp_path, stage, says):
    with pytest.raises(GateError, match=says):
        load_plan(write_plan(tmp_path / "plan.yaml", {"sim": stage}))


def test_a_run_on_a_stage_with_no_gates_is_refused_before_it_runs(tmp_path):
    """`--scenario` gives a stage the plan left without runs: its run could only end inconclusive."""
    plan, site, _ = two_runs_at_sim(tmp_path, 1)
    scenario = tmp_path / "one.yaml"
    scenario.write_text("{name: one, seed: 2, acceptance_cycles: 1}\n")
    result = cli("run", "--cell", CELL, "--stage", "sim", "--plan", str(write_plan(plan, {})), "--scenario",
                 str(scenario), "--site", str(site))
    assert result.exit_code == 2 and result.stderr.count("\n") == 1 and "the plan has no gates for sim" in result.stderr
    assert not (site / "runs").exists()
