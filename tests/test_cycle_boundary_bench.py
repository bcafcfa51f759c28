"""``benchmarks/realtime.py --cycle-seconds``: the figure can include cycle ends, and its JSON shows them; a bad
value is one line and exit 2 before any work; without it a run is one cycle, as before."""

from __future__ import annotations

import subprocess
import sys

import pytest
from test_bench_scripts_server_output import BENCH, _realtime


@pytest.mark.parametrize("cycle_seconds, cycles", [(None, 1), (0.5, 3)])
def test_a_run_of_cycles_shows_its_cycle_ends(tmp_path, cycle_seconds, cycles):
    run = _realtime().one_run(200.0, "sway", "thread", 1.5, tmp_path / "unused.onnx", 0, tmp_path / "run",
                              cycle_seconds=cycle_seconds)
    assert "refused" not in run, run
    assert run["cycles"] == cycles and run["cycle_seconds"] == (cycle_seconds or 1.5)
    assert run["between_cycles_ms"]["count"] == cycles - 1
    assert "pauses_between_stretches" in run


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "30", "3", "1e-9"])
def test_a_cycle_length_outside_the_run_is_refused_in_one_line(tmp_path, value):
    """Outside the run, not a whole fraction of it (3 s of 20 ran 7 cycles, 21 s, said to be 20), or more cycles than
    the bound (1e-9 s: every run refused by the scenario, not the command)."""
    done = subprocess.run([sys.executable, str(BENCH / "realtime.py"), "--seconds", "20", "--cycle-seconds", value],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.strip().splitlines()[-1].endswith(f"--cycle-seconds: a whole fraction of --seconds (20), at "
                                                         f"most 100000 cycles, got {float(value):g}")
    assert list(tmp_path.iterdir()) == []
