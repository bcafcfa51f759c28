"""A cycle buffer that cannot grow (no memory for its next chunk) ends its growth, not the run: under an address-space
limit a 3,600 s quadruped cycle raised MemoryError in ``CycleBuffer.add`` at tick 819,200, a traceback through the
servo loop, rc 1, the record cut short. Now the buffer keeps its first rows, the cycle has no tick features (read from
its start only, a healthy cell's currents read as a load change) and no cycle monitor's reading (joining the columns
needs more memory still), the outcome says how many seconds the buffer held, one ``cycle_buffer_full`` event a cycle
says so (routine: no safety event), and the record holds every tick."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np

from cellguard.diagnose import cycle_buffer
from cellguard.diagnose.cycle_buffer import BLOCK, CycleBuffer
from cellguard.record.reader import open_record
from cellguard.runtime import Run, run_scenario
from cellguard.scenario import parse_scenario


def test_a_buffer_under_an_address_space_limit_keeps_what_it_holds_and_drops_the_rest():
    """A real limit (RLIMIT_AS: what the process has plus 100 MB) and 12 joints: the chunks it can allocate fill,
    then every tick is refused (False), counted, never raised; the rows held read back and fold whole."""
    script = textwrap.dedent("""
        import resource
        import numpy as np
        from cellguard.diagnose.cycle_buffer import BLOCK, CycleBuffer
        from cellguard.robot.state import State

        size = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmSize:"))
        resource.setrlimit(resource.RLIMIT_AS, ((size + 100 * 1024) * 1024, resource.getrlimit(resource.RLIMIT_AS)[1]))
        buffer = CycleBuffer(12, 3_612_001)
        row = np.ones(12)
        kept = [buffer.add(row, row, State(k * 1_000_000, row, row, row, row)) for k in range(300_000)]
        first = kept.index(False)
        assert not any(kept[first:]) and buffer.n == first and buffer.dropped == 300_000 - first
        assert buffer.n % buffer.chunk_rows == 0 and buffer.fold_rest() == 0
        assert buffer.rows("q").shape == (first, 12) and buffer.stamp(first - 1) == (first - 1) * 1_000_000
        print(first)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert 0 < int(done.stdout) < 300_000  # the limit bit: a few chunks of 32,768 ticks held


def test_a_run_whose_buffer_cannot_grow_goes_on_with_one_event_a_cycle_and_records_every_tick(tmp_path, monkeypatch):
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 1, "acceptance_cycles": 2, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 2}}))
    run.ticks = CycleBuffer(run.cell.profile.dof, BLOCK)  # chunks of one block: 0.512 s at 1 kHz

    def no_memory(*_):
        raise MemoryError("Unable to allocate 1.1 MiB for an array")  # as numpy says it under RLIMIT_AS

    monkeypatch.setattr(cycle_buffer, "_Chunk", no_memory)  # the buffer's next chunk, and only that
    run.cycle_monitors.append(lambda ticks, outcome: outcome.update(monitored=ticks.rows("current").shape))
    summary = run_scenario(run.scenario, tmp_path / "out", run=run)
    assert "stopped" not in summary, summary.get("stopped")
    full = [e for e in run.events if e.kind == "cycle_buffer_full"]
    assert len(full) == 2 and "no tick features" in full[0].reason, full
    for outcome in run.cycles:
        assert outcome["buffer_full_after_s"] < 0.52 and "current_rms.shoulder_pan" not in outcome["features"]
        assert "monitored" not in outcome and outcome["features"]["latency_mean_ms"] >= 0.0
    with open_record(tmp_path / "out") as rec:
        ticks = rec.ticks(rate="all")
        assert [e.kind for e in rec.events()].count("cycle_buffer_full") == 2
    assert len(ticks) > 4000  # every tick of both 2 s cycles, not the 2 x 512 the buffer held
    assert np.isfinite(ticks.current).all()
