"""The cycle buffer's storage grows by chunks: a long cycle's limit is not reserved up front, rows once stored are
never moved (no copy on the servo path), and what is read back (rows, blocks, stamps, block sums) is what was added,
over cycles of any length, the buffer cleared and reused between them."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cellguard.diagnose.cycle_buffer import BLOCK, CURRENT_SQ, TRAVEL, CycleBuffer
from cellguard.robot.registry import make_cell
from cellguard.robot.state import State
from cellguard.runtime.loop import _limit_s
from cellguard.scenario import parse_scenario

COLUMNS = ("t_ns", "reference", "setpoint", "q", "qd", "effort", "current")


def _add(buffer: CycleBuffer, n: int, dof: int, seed: int) -> dict[str, np.ndarray]:
    """``n`` ticks of random data into ``buffer``; returns them by column."""
    rng = np.random.default_rng(seed)
    data = {"t_ns": 10 ** 9 + np.cumsum(rng.integers(1, 2_000_000, n)),
            **{name: rng.standard_normal((n, dof)) for name in COLUMNS[1:]}}
    for k in range(n):
        buffer.add(data["reference"][k], data["setpoint"][k],
                   State(int(data["t_ns"][k]), *(data[name][k] for name in ("q", "qd", "effort", "current"))))
    return data


@settings(max_examples=40, deadline=None)
@given(lengths=st.lists(st.integers(0, 3 * BLOCK + 5), min_size=1, max_size=4), dof=st.integers(1, 4),
       capacity=st.integers(1, 4 * BLOCK), seed=st.integers(0, 2 ** 32 - 1))
def test_what_is_read_back_is_what_was_added_over_cycles_of_any_length(lengths, dof, capacity, seed):
    buffer = CycleBuffer(dof, capacity)
    for i, n in enumerate(lengths):
        buffer.clear()
        data = _add(buffer, n, dof, seed + i)
        assert buffer.n == n and buffer.fold_rest() == n % BLOCK
        for name in COLUMNS:
            np.testing.assert_array_equal(buffer.rows(name), data[name])
            for k in range(buffer.blocks):
                np.testing.assert_array_equal(buffer.block(name, k), data[name][k * BLOCK:(k + 1) * BLOCK])
        assert [buffer.stamp(j) for j in range(n)] == data["t_ns"].tolist()
        sums, t_range = buffer.sums, buffer.t_range
        assert sums.shape == (buffer.blocks, 6, dof) and t_range.shape == (buffer.blocks, 2)
        for k in range(buffer.blocks):
            rows = slice(k * BLOCK, (k + 1) * BLOCK)
            np.testing.assert_allclose(sums[k, CURRENT_SQ], (data["current"][rows] ** 2).sum(axis=0))
            np.testing.assert_allclose(sums[k, TRAVEL], np.abs(data["qd"][rows]).sum(axis=0))
            assert t_range[k].tolist() == [data["t_ns"][rows].min(), data["t_ns"][rows].max()]


def test_rows_stored_are_never_moved_as_the_buffer_grows_past_its_capacity():
    """A view of the first block taken before the cycle outgrew the buffer's first chunk is still that block after
    (growing by copying the arrays moved them: a copy of everything stored, on one servo tick)."""
    buffer = CycleBuffer(2, BLOCK)
    data = _add(buffer, BLOCK, 2, 0)
    first = buffer.block("current", 0)
    more = _add(buffer, 5 * BLOCK, 2, 1)
    assert np.shares_memory(first, buffer.block("current", 0))
    np.testing.assert_array_equal(first, data["current"])
    np.testing.assert_array_equal(buffer.rows("current"), np.concatenate([data["current"], more["current"]]))


def test_a_cycle_that_fits_in_one_chunk_is_read_back_without_a_copy():
    buffer = CycleBuffer(3, 3 * BLOCK)
    _add(buffer, 2 * BLOCK + 7, 3, 0)
    assert np.shares_memory(buffer.rows("q"), buffer.block("q", 0))


def test_a_3600_s_cycle_limit_is_not_reserved_up_front_under_a_500_mb_address_space_limit():
    """The quadruped (12 joints, 1 kHz) on a 3,600 s time cycle: the buffer loop.py builds (its ticks up to the
    time-out, ``_limit_s``) and the first 40 s of ticks fit under ``ulimit -v`` of what the process has plus 500 MB
    (the whole limit reserved up front was 2 GB; the whole cycle's rows, 2 GB, do not fit: see
    test_cycle_buffer_memory)."""
    cell = make_cell("quadruped-turns")
    capacity = round(_limit_s(parse_scenario({"cell": cell.name, "cycle": {"source": "time", "seconds": 3600}}).cycle)
                     * 1e9 / cell.dt_ns) + 1
    script = textwrap.dedent(f"""
        import resource
        import numpy as np
        from cellguard.diagnose.cycle_buffer import CycleBuffer
        from cellguard.robot.state import State

        size = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmSize:"))
        limit = (size + 500 * 1024) * 1024
        resource.setrlimit(resource.RLIMIT_AS, (limit, resource.getrlimit(resource.RLIMIT_AS)[1]))
        buffer = CycleBuffer({cell.profile.dof}, {capacity})
        row = np.ones({cell.profile.dof})
        for k in range(40_000):
            assert buffer.add(row, row, State(k * {cell.dt_ns}, row, row, row, row))
        print(buffer.n)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["40000"]
