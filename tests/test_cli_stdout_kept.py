"""A command that has written, moved or deleted something and then cannot write its stdout (closed, full) exits 1
with the line naming what is kept: release create, promote, run, rollback and report, identify --write, replay,
diagnose, train-demo-policy and fleet push and withdraw did their work and exited 2, which says nothing was done.
Every command is listed below as writing or not, so that a new one is checked too. Also: a production release
whose gates fail with no last_good to roll back to says that it stays current (the output said only 'fail')."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest
import typer.main
from release_helpers import CELL, KNOCKED, cli, log_pass, stored_release, write_plan

from cellguard.cli import app

CLI = [sys.executable, "-c", "from cellguard.cli import app; app()"]
KEPT = " is written and kept"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A run folder: 5 acceptance cycles (a baseline) and 1 production cycle."""
    from cellguard.runtime import run_scenario
    from cellguard.scenario import parse_scenario

    out = tmp_path_factory.mktemp("kept") / "run"
    run_scenario(parse_scenario({"cell": CELL, "seed": 3, "acceptance_cycles": 5, "production_cycles": 1}), out)
    return out


def _store(tmp_path):
    from cellguard.release import Store

    return Store(tmp_path / "site")


def _release_create(tmp_path, recorded):
    from cellguard.release import create_bundle

    rid = create_bundle("scripted", None, CELL, None, note="kept").id
    site = tmp_path / "site"
    return (["release", "create", "--policy", "scripted", "--profile", CELL, "--note", "kept", "--site", str(site)],
            f"release {rid} in {site}")


def _release_promote(tmp_path, recorded):
    rid = stored_release(_store(tmp_path), "kept")
    return (["release", "promote", rid, "--cell", CELL, "--to", "sim", "--site", str(tmp_path / "site")],
            f"log entry 1 ({rid} current at sim on {CELL})")


def _release_run(tmp_path, recorded):
    from cellguard.release import promote

    store = _store(tmp_path)
    promote(store, stored_release(store, "kept"), CELL, "sim")
    plan = write_plan(tmp_path / "plan.yaml", {"sim": {"runs": [{"name": "one", "seed": 5, "acceptance_cycles": 1}],
                                                       "gates": [{"metric": "success_rate", "min": 0}]}})
    return (["release", "run", "--cell", CELL, "--stage", "sim", "--plan", str(plan), "--site", str(store.site)],
            f"log entry 2 (sim gates on {CELL}: pass) with its records in {store.site / 'runs' / CELL / 'sim'}")


def _release_rollback(tmp_path, recorded):
    from cellguard.release import promote

    store = _store(tmp_path)
    good, newer = stored_release(store, "good"), stored_release(store, "newer")
    log_pass(store, "pilot", good)
    promote(store, good, CELL, "production")
    log_pass(store, "production", good)  # good is last_good there
    log_pass(store, "pilot", newer)
    promote(store, newer, CELL, "production")  # log entry 5
    return (["release", "rollback", "--cell", CELL, "--site", str(store.site)],
            f"log entry 6 (production on {CELL} back to {good})")


def _release_report(tmp_path, recorded):
    rid = stored_release(_store(tmp_path), "kept")
    page = tmp_path / "release.html"
    return (["release", "report", rid, "-o", str(page), "--site", str(tmp_path / "site")], f"the release page {page}")


def _identify(tmp_path, recorded):
    from cellguard.calibrate.excitation import excitation_scenario, excite
    from cellguard.robot.arm_cell import ASSETS

    excite(excitation_scenario(CELL, 2.0), tmp_path / "ex")
    profile = tmp_path / "arm_profile.yaml"
    profile.write_bytes((ASSETS / "arm_profile.yaml").read_bytes())
    return (["identify", str(tmp_path / "ex"), "--only", "elbow,friction", "--write", str(profile)],
            "calibration version ")  # its name holds the date


def _replay(tmp_path, recorded):
    page = tmp_path / "replay.html"
    return ["replay", str(recorded), "--cycle", "5", "-o", str(page)], f"the replay page {page}"


def _report(tmp_path, recorded):
    page = tmp_path / "report.html"
    return ["report", str(recorded), "-o", str(page)], str(page)


def _diagnose(tmp_path, recorded):
    fresh = shutil.copytree(recorded, tmp_path / "run")
    (fresh / "baseline.json").unlink(missing_ok=True)  # report's test may have diagnosed the record first
    return ["diagnose", str(fresh)], f"the diagnosis in {fresh} (baseline.json, fixes.json)"


def _excite(tmp_path, recorded):
    return ["excite", CELL, "--seconds", "7", "--out", str(tmp_path / "ex")], f"the record in {tmp_path / 'ex'}"


def _train_demo_policy(tmp_path, recorded):
    model = tmp_path / "p.onnx"
    return (["train-demo-policy", "-o", str(model), "--cycles", "2", "--random-features", "0"],
            f"the policy {model}")


def _fleet_push(tmp_path, recorded):
    policy = tmp_path / "policy.yaml"
    policy.write_text("tenant: ta\nsite: s1\nexport: signatures\n")
    site_dir = tmp_path / "fleet"
    return (["fleet", "push", str(recorded), "--policy", str(policy), "--site-dir", str(site_dir)],
            f" in the audit log of {site_dir}")  # after the batch's id


def _fleet_withdraw(tmp_path, recorded):
    from cellguard.fleet.landing import write_signatures
    from cellguard.fleet.synthetic import rows_of, synthetic_fleet

    seed = {"cause": "friction", "robot_model": "arm5", "cell_type": CELL, "confidence": 0.8, "onset_cycle": 7,
            "detection_delay_cycles": 2, "effects": {"current_rms.elbow": 6.0}}
    rows = rows_of(*synthetic_fleet([seed], 3, tenants=1, sites_per_tenant=1, days=1, versions=1, seed=5))
    write_signatures(tmp_path / "lake", rows, "batch-1")
    policy = tmp_path / "policy.yaml"
    policy.write_text(f"tenant: {rows[0]['tenant_id']}\nsite: {rows[0]['site_id']}\nexport: signatures\n")
    (tmp_path / "fleet").mkdir()  # the site's folder: the withdrawal is logged in its audit log
    return (["fleet", "withdraw", "--policy", str(policy), "--lake", str(tmp_path / "lake"), "--site-dir",
             str(tmp_path / "fleet")],
            f"the withdrawal of site {rows[0]['site_id']} (0 row(s) from the store, 3 signature(s) from the lake)")


# command -> (tmp_path, run folder) -> (its arguments, what its line names as kept, or a part of that)
WRITERS = {"release create": _release_create, "release promote": _release_promote, "release run": _release_run,
           "release rollback": _release_rollback, "release report": _release_report, "identify": _identify,
           "replay": _replay, "report": _report, "diagnose": _diagnose, "excite": _excite,
           "train-demo-policy": _train_demo_policy, "fleet push": _fleet_push, "fleet withdraw": _fleet_withdraw}
ELSEWHERE = {"run", "demo"}  # test_cli_stdout.py runs `run`; demo's run (too long here) marks its record the same
STDERR_ONLY = {"record export", "record to-lerobot", "record recover"}  # they write, and print on stderr alone
READ_ONLY = {"bench", "embodiment show", "fleet audit", "fleet query", "fleet similar", "record info", "record query",
             "release status", "release verify", "sim-server"}


def _commands(cmd, prefix: tuple = ()):
    if hasattr(cmd, "commands"):
        for name, sub in cmd.commands.items():
            yield from _commands(sub, (*prefix, name))
    else:
        yield " ".join(prefix)


def test_every_command_is_listed_as_writing_or_not():
    """A new command is put in one list; a writer, in WRITERS, is then run below with its stdout failing."""
    assert set(_commands(typer.main.get_command(app))) == set(WRITERS) | ELSEWHERE | STDERR_ONLY | READ_ONLY


@pytest.mark.parametrize("command", sorted(WRITERS))
def test_a_writer_whose_stdout_fails_afterwards_exits_1_naming_what_is_kept(command, tmp_path, recorded):
    args, kept = WRITERS[command](tmp_path, recorded)
    closed = command.startswith(("release", "fleet"))  # the others on a full disk: both kinds of failure
    with open("/dev/full", "w") as full:
        done = subprocess.run(CLI + args, cwd=tmp_path, stdout=subprocess.DEVNULL if closed else full,
                              stderr=subprocess.PIPE, text=True, timeout=300,
                              preexec_fn=(lambda: os.close(1)) if closed else None)
    assert done.returncode == 1, done.stderr
    why = "stdout is closed" if closed else "No space left on device"
    line, head = done.stderr.splitlines()[-1], f"error: stdout: cannot write the output ({why}); "
    assert line.startswith(head) and line.endswith(KEPT) and kept in line.removeprefix(head).removesuffix(KEPT), line


@pytest.mark.parametrize("command", sorted(STDERR_ONLY))
def test_a_writer_that_prints_on_stderr_alone_ends_well_with_stdout_closed(command, tmp_path, recorded):
    out = tmp_path / ("ticks.csv" if command == "record export" else "out")
    done = subprocess.run(CLI + [*command.split(), str(recorded), "-o", str(out)], stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True, timeout=300, preexec_fn=lambda: os.close(1))
    assert done.returncode == 0 and "error" not in done.stderr and out.exists(), done.stderr


def test_production_failing_with_no_last_good_says_it_stays_current(tmp_path):
    """README: a failing gate moves current back to last_good; with none, nothing moved and the output said 'fail'."""
    from cellguard.release import promote

    store = _store(tmp_path)
    rid = stored_release(store, "first")
    log_pass(store, "pilot", rid)
    promote(store, rid, CELL, "production")
    write_plan(store.site / "release-plan.yaml", {"production": {"runs": [KNOCKED],  # in force: its fail acts
                                                                 "gates": [{"metric": "success_rate", "min": 1.0}]}})
    result = cli("run", "--cell", CELL, "--stage", "production", "--site", str(store.site))
    assert result.exit_code == 1, result.output
    assert (f"nothing to roll back to: {rid} stays current at production on {CELL} (no other release is last_good "
            f"there)") in " ".join(result.stdout.split())  # as rich wraps it
    assert store.pointers(CELL, "production").current == rid


def test_a_second_diagnosis_names_only_the_file_it_wrote(tmp_path, recorded):
    """The kept line named baseline.json on every diagnosis; it is written only when no stored one fits."""
    fresh = shutil.copytree(recorded, tmp_path / "run")
    (fresh / "baseline.json").unlink(missing_ok=True)  # another test's report may have diagnosed the record
    lines = []
    for _ in range(2):
        with open("/dev/full", "w") as full:
            done = subprocess.run(CLI + ["diagnose", str(fresh)], stdout=full, stderr=subprocess.PIPE, text=True,
                                  timeout=300)
        assert done.returncode == 1, done.stderr
        lines.append(done.stderr.splitlines()[-1])
    assert lines[0].endswith(f"the diagnosis in {fresh} (baseline.json, fixes.json){KEPT}")
    assert lines[1].endswith(f"the diagnosis in {fresh} (fixes.json){KEPT}")
