"""Run summary and diagnosis leftovers. A stopped run with no retreat event read "robot: no retreat played (home
already, or no home pose)": the summary now holds how far the last measured pose lies from home, and the line says
it. A start-up refusal under --overwrite said "the record in DIR is finished and whole" and not that the previous
record was gone. A cycle whose tick buffer filled (``cycle_buffer_full``) was left out of diagnose's comparison
without a word: a shorter comparison read as a healthy one."""

from __future__ import annotations

import json
import re
import signal

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from cellguard.cli import app
from cellguard.cli.errors import exit_if_stopped
from cellguard.diagnose import cycle_buffer
from cellguard.diagnose.cycle_buffer import BLOCK, CycleBuffer
from cellguard.diagnose.from_record import diagnose_record
from cellguard.record.reader import open_record
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import parse_scenario

HOME = np.array([0.0, -0.3, 1.9, 1.55, 0.0, 0.025])  # the arm cell's home pose


def _held_at_home(tmp_path, *, home: bool) -> Run:
    """A run on the arm cell whose policy holds the home pose (no approach, nothing to retreat), stopped by the
    operator mid-cycle; ``home=False``: the robot has no home pose (a bridge given none)."""
    np.savez(tmp_path / "home.npz", t=np.arange(40) * 0.1, actions=np.tile(HOME, (40, 25, 1)), dt=np.float64(0.02))
    run = Run(parse_scenario({"cell": "arm-pick-place", "policy": f"replay:{tmp_path / 'home.npz'}",
                              "acceptance_cycles": 1, "production_cycles": 1,
                              "cycle": {"source": "time", "seconds": 2}}))
    if not home:
        run.cell.q_home = None
    write, writes = run.cell.write, []

    def pressed(setpoint):  # the operator's Ctrl-C 1.5 s in
        writes.append(1)
        if len(writes) == 1500:
            signal.raise_signal(signal.SIGINT)
        return write(setpoint)

    run.cell.write = pressed
    return run


def _stopped_line(summary: dict, out, capsys, replaced: bool = False) -> str:
    capsys.readouterr()
    with pytest.raises(typer.Exit) as ended:
        exit_if_stopped(summary, out, replaced)
    assert ended.value.exit_code == 130
    return capsys.readouterr().err.strip()


def test_a_stop_with_no_retreat_says_how_far_from_home_the_robot_was_measured(tmp_path, capsys):
    run = _held_at_home(tmp_path, home=True)
    summary = run_scenario(run.scenario, tmp_path / "run", run=run)
    assert not any(e["kind"].startswith("retreat") for e in summary["events"])  # nothing told where it was
    far = summary["from_home"]
    gap = np.abs(run.link.state.q - HOME)
    arm = int(np.argmax(gap[:5]))  # five hinges (rad), then the gripper's slide (m): each unit's farthest
    assert far == [{"joint": run.cell.profile.joint_names[arm], "distance": float(gap[arm]), "unit": "rad"},
                   {"joint": "gripper", "distance": float(gap[5]), "unit": "m"}]
    assert max(f["distance"] for f in far) < 0.01  # held at home: a tracking error's worth
    assert json.loads((tmp_path / "run" / "summary.json").read_text())["from_home"] == far
    line = _stopped_line(summary, tmp_path / "run", capsys)
    shown = re.search(r"robot: (\w+) (under )?([0-9.]+) mrad, gripper (under )?([0-9.]+) mm from home \(the farthest "
                      r"joint of each unit; no retreat played\)$", line)
    assert shown is not None, line
    assert shown[1] == far[0]["joint"]
    for under, value, f in ((shown[2], shown[3], far[0]), (shown[4], shown[5], far[1])):
        milli = f["distance"] * 1e3
        assert milli < 0.01 if under else float(value) == pytest.approx(milli, rel=1e-2)


def test_a_stop_on_a_robot_with_no_home_pose_says_so(tmp_path, capsys):
    run = _held_at_home(tmp_path, home=False)
    summary = run_scenario(run.scenario, tmp_path / "run", run=run)
    assert summary["from_home"] is None
    assert _stopped_line(summary, tmp_path / "run", capsys).endswith(
        "; robot: no retreat played (no home pose for this robot)")


@pytest.mark.parametrize("far, said", [
    ([{"joint": "elbow", "distance": 1.23, "unit": "rad"}], "elbow 1.23 rad"),
    ([{"joint": "elbow", "distance": 3e-4, "unit": "rad"}, {"joint": "gripper", "distance": 0.017, "unit": "m"}],
     "elbow 0.3 mrad, gripper 17 mm"),  # a closed gripper's 17 mm no longer hides the arm
    ([{"joint": "gripper", "distance": 6e-9, "unit": "m"}], "gripper under 0.01 mm"),
])
def test_the_distance_from_home_is_said_in_its_joints_unit(tmp_path, capsys, far, said):
    summary = {"stopped": "operator stop (SIGINT)", "events": [], "from_home": far}
    assert f"; robot: {said} from home (the farthest joint of each unit; no retreat played)" in _stopped_line(
        summary, tmp_path, capsys)


def test_an_old_summary_without_the_distance_still_reads(tmp_path, capsys):
    summary = {"stopped": "operator stop (SIGINT)", "events": [{"t_ns": 1, "kind": "operator_stop", "category": 2}]}
    assert _stopped_line(summary, tmp_path, capsys).endswith(
        "; robot: no retreat played (home already, or no home pose)")


def _cli_run(tmp_path, text: str, out, *extra: str):
    (tmp_path / "s.yaml").write_text(text)
    return CliRunner().invoke(app, ["run", str(tmp_path / "s.yaml"), "--out", str(out), *extra])


@pytest.mark.parametrize("before", [True, False])
def test_a_start_up_refusal_under_overwrite_says_the_previous_record_was_replaced(tmp_path, before):
    """A one-step chunk of 1 ms cannot cover the simulated 10 ms latency: refused on the first chunk, the record
    started (the old one replaced); the line says so only where there was one."""
    out = tmp_path / "out"
    if before:
        ran = _cli_run(tmp_path, "cell: arm-pick-place\nacceptance_cycles: 1\nproduction_cycles: 0\n"
                                 "cycle: {source: time, seconds: 0.5}\n", out)
        assert ran.exit_code == 0, ran.output
    np.savez(tmp_path / "short.npz", t=np.arange(0.0, 2.0, 0.05), actions=np.broadcast_to(HOME, (40, 1, 6)), dt=0.001)
    result = _cli_run(tmp_path, f"cell: arm-pick-place\npolicy: replay:{tmp_path / 'short.npz'}\nacceptance_cycles: 1\n"
                                "production_cycles: 0\ncycle: {source: time, seconds: 1}\n", out, "--overwrite")
    assert result.exit_code == 2, result.output
    replaced = ", which replaced the previous one (--overwrite)," if before else ""
    assert result.stderr.endswith(f"; the record in {out}{replaced} is finished and whole; it has no summary.json\n")
    with open_record(out) as rec:
        assert [e.kind for e in rec.events()].count("startup_refused") == 1


FULL = (6, 7)  # the production cycles whose tick buffer fills


def test_diagnose_says_how_many_cycles_had_no_tick_features_and_why(tmp_path, monkeypatch):
    """The loop's own buffer, refused its next chunk (as numpy refuses under RLIMIT_AS), in two production cycles:
    each has a ``cycle_buffer_full`` event and no tick features; diagnose's text and --json count them."""
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 2, "acceptance_cycles": 5, "production_cycles": 3}))
    whole, small = run.ticks, {k: CycleBuffer(run.cell.profile.dof, BLOCK) for k in FULL}  # one block: 0.512 s

    def no_memory(*_):
        raise MemoryError("Unable to allocate 1.1 MiB for an array")

    monkeypatch.setattr(cycle_buffer, "_Chunk", no_memory)  # a buffer's next chunk; the loop's whole one needs none
    out = tmp_path / "run"
    summary = run_scenario(run.scenario, out, run=run,
                           on_cycle=lambda _: setattr(run, "ticks", small.get(run.cycles.total, whole)))
    full = [c["cycle"] for c in summary["cycles"] if "buffer_full_after_s" in c]
    assert full == list(FULL) and "current_rms.elbow" not in summary["cycles"][FULL[0]]["features"]
    told = diagnose_record(out).to_dict()["cycles_without_tick_features"]
    assert told["count"] == 2 and told["cycles"] == list(FULL) and "cycle_buffer_full" in told["why"]
    result = CliRunner().invoke(app, ["diagnose", str(out), "--json"])
    assert json.loads(result.stdout)["cycles_without_tick_features"] == told
    text = " ".join(CliRunner().invoke(app, ["diagnose", str(out)]).stdout.split())  # as rich wraps it
    assert "note: 2 production cycle(s) without tick features: the tick buffer filled (cycle_buffer_full" in text
    assert "(cycles 6, 7)" in text
    from cellguard.report.from_record import write_report

    page = write_report(out).read_text()  # the report says it too: a shorter comparison read as a healthy one
    assert "2 production cycle(s) without tick features" in page and "(cycles 6, 7)" in page


def test_a_stopped_run_that_replaced_a_record_says_so(tmp_path, capsys):
    """--overwrite and a stop (Ctrl-C here): the previous record is gone; the line said only "the record in DIR"."""
    from cellguard.cli.run import replaces

    out = tmp_path / "run"
    run = _held_at_home(tmp_path, home=True)
    assert not replaces(out, True)
    summary = run_scenario(run.scenario, out, run=run)
    assert replaces(out, True) and not replaces(out, False)
    assert "which replaced the previous one (--overwrite), is complete" in _stopped_line(summary, out, capsys, True)
    assert "replaced" not in _stopped_line(summary, out, capsys)
