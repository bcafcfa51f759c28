"""The benchmark scripts' command lines: ``--help`` prints usage and runs nothing, bad input is one line and exit 2
before any work, and a SIGTERM or SIGKILL leaves no pool worker behind. Only the refusal and help paths run here
(each script runs in its own session, killed whole if it outlives its time, so a regression cannot leave a benchmark
running)."""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def start(script: str, *args: str, cwd: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(BENCH / script), *args], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)


def finish(proc: subprocess.Popen, timeout: float) -> tuple[int, str, str]:
    """(exit code, stdout, stderr); the whole session killed and the test failed if it takes longer."""
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail(f"{proc.args[1:]} still running after {timeout} s")
    return proc.returncode, out, err


def bench(script: str, *args: str, cwd: Path, timeout: float = 60) -> tuple[int, str, str]:
    return finish(start(script, *args, cwd=cwd), timeout)


def descendants(pid: int) -> list[int]:
    children = [int(c) for c in subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout.split()]
    return children + [d for c in children for d in descendants(c)]


def alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


@pytest.mark.parametrize("script", ["fleet_runs.py", "sim_speed.py", "guard.py", "realtime.py"])
def test_help_prints_usage_and_runs_nothing(tmp_path, script):
    code, out, err = bench(script, "--help", cwd=tmp_path, timeout=30)
    assert (code, err) == (0, "") and out.startswith("usage: ")
    assert list(tmp_path.iterdir()) == []  # fleet_runs.py made its fleet in a folder named --help


@pytest.mark.parametrize("script, args, says", [
    ("sim_speed.py", ["0"], "cycles: at least 1, got 0"),
    ("sim_speed.py", ["x"], "argument cycles: invalid int value: 'x'"),
    ("fleet_runs.py", ["a", "b"], "unrecognized arguments: b"),
    # the sim-server serves whole 1 ms steps only: 400 Hz ran, each run "does not answer (ConnectionRefusedError)"
    ("realtime.py", ["--rates", "1000,400"], "--rates: 400 Hz is not served: a servo period is a whole number of the "
                                             "cell's 1 ms physics steps; nearest rates served: 333.3 and 500 Hz"),
    ("realtime.py", ["--seconds", "1e308"], "--seconds: more than 0 and at most 604800 s (a week), got 1e+308"),
    ("realtime.py", ["--seconds", "inf"], "--seconds: more than 0 and at most 604800 s (a week), got inf"),
    ("realtime.py", ["--floor-seconds", "inf"], "--floor-seconds: more than 0 and at most 604800 s (a week), got inf"),
    ("realtime.py", ["--floor-seconds", "1e308"], "--floor-seconds: more than 0 and at most 604800 s (a week), "
                                                  "got 1e+308"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, script, args, says):
    # the smallest run there is, should the refusal be missed: one second, one policy, one worker
    quick = ["--seconds", "1", "--floor-seconds", "1", "--policies", "sway", "--workers", "thread"]
    code, out, err = bench(script, *(quick if script == "realtime.py" else []), *args, cwd=tmp_path)
    assert (code, out) == (2, "")
    assert err.splitlines()[-1] == f"{script}: error: {says}" and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_a_sim_server_that_ends_is_reported_in_its_own_words(tmp_path):
    """A server that refuses its rate (past main's check) is the run's ``refused``, not "does not answer"."""
    spec = importlib.util.spec_from_file_location("bench_realtime", BENCH / "realtime.py")
    realtime = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(realtime)
    run = realtime.one_run(400.0, "sway", "thread", 1.0, tmp_path / "unused.onnx", 0, tmp_path / "run")
    assert run["refused"] == ("sim-server ended (exit code 2): error: --rate-hz: 400 Hz is not served: a servo period "
                              "is a whole number of the cell's 1 ms physics steps; nearest rates served: 333.3 and "
                              "500 Hz")


def in_a_run(proc: subprocess.Popen, runs: Path) -> list[int]:
    """The pool workers of fleet_runs.py (``proc``, making its runs in ``runs``) once one of them is inside a run."""
    deadline = time.monotonic() + 60
    while not list(runs.glob("*.partial")) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None and list(runs.glob("*.partial")), "no run started: nothing tested"
    workers = descendants(proc.pid)
    assert workers
    return workers


def made(runs: Path) -> set[str]:
    return {d.name for d in runs.iterdir() if (d / "summary.json").is_file()}


@pytest.mark.parametrize("to_group, one_left", [(True, False), (False, False), (True, True)],
                         ids=["group", "main-only", "group-one-run-left"])
def test_sigterm_ends_fleet_runs_with_its_workers_and_keeps_no_stopped_run(tmp_path, monkeypatch, to_group, one_left):
    """``timeout`` signals the whole group (each worker's run took it as an operator stop, and the stopped run was
    kept as the site's); ``kill PID`` the script alone (its workers then waited on their queue for good). No job
    starts after the signal: the jobs queued in the pool, up to three whole runs, were made first (all by one worker
    where the signal had ended the other between two jobs), and where a worker waited for a job (one run left to
    make) the signal ended it, the pool broke and the script waited for good on the queue's lock the dead worker
    held."""
    runs = tmp_path / "runs"
    if one_left:  # every run but the acceptance run is there (``summary.json`` is what the script looks for)
        spec = importlib.util.spec_from_file_location("bench_fleet_runs", BENCH / "fleet_runs.py")
        fleet_runs = importlib.util.module_from_spec(spec)
        monkeypatch.setitem(sys.modules, spec.name, fleet_runs)  # its dataclass looks itself up there
        spec.loader.exec_module(fleet_runs)
        _, sites, held = fleet_runs.plan()
        for r in (*sites, *held):
            (runs / r.name).mkdir(parents=True)
            (runs / r.name / "summary.json").write_text("{}")
    proc = start("fleet_runs.py", str(runs), cwd=tmp_path)
    try:
        workers = in_a_run(proc, runs)
        before = made(runs)
        (os.killpg if to_group else os.kill)(proc.pid, signal.SIGTERM)
        code, out, _ = finish(proc, 60)
        deadline = time.monotonic() + 10
        while any(map(alive, workers)) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert [w for w in workers if alive(w)] == []
    finally:  # whatever a failure left of the session
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert (code, out) == (128 + signal.SIGTERM, "")
    kept = [json.loads((d / "summary.json").read_text()) for d in runs.iterdir() if (d / "summary.json").is_file()]
    assert [s["stopped"] for s in kept if s.get("stopped")] == []
    assert list(runs.glob("*.partial")) == []
    # the runs under way when the script alone was signalled (two at a time) are made whole; no other
    assert len(made(runs) - before) <= (0 if to_group else 2)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the death signal is Linux's (prctl)")
def test_sigkill_of_fleet_runs_ends_its_workers(tmp_path):
    """SIGKILL runs no handler and shuts no pool down: the workers made their runs for minutes, orphaned, then
    waited on their queue for good. They get the death signal now."""
    runs = tmp_path / "runs"
    proc = start("fleet_runs.py", str(runs), cwd=tmp_path)
    try:
        workers = in_a_run(proc, runs)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + 5
        while any(map(alive, workers)) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert [w for w in workers if alive(w)] == []
    finally:  # whatever is left of its session
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the death signal is Linux's (prctl)")
def test_fleet_runs_workers_run_whatever_the_default_start_method():
    """Under forkserver (Linux's default from Python 3.14) a worker's parent is the server: each ended at once in its
    set-up, and the pool broke before a run was made."""
    script = ("import multiprocessing, sys; multiprocessing.set_start_method('forkserver'); "
              f"sys.path.insert(0, {str(BENCH)!r}); import fleet_runs\n"
              "with fleet_runs._pool(2) as pool:\n    print(list(pool.map(abs, [-1, -2, -3])))")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert (done.returncode, done.stdout) == (0, "[1, 2, 3]\n"), done.stderr[-2000:]
