"""Per-cycle features from the buffer's per-block sums equal the plain whole-array computation, and a cycle's end
reads only the rows after the last whole block (its cost does not grow with the cycle's length; timing is in
the report, not asserted here)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellguard.diagnose.cycle_buffer import CycleBuffer
from cellguard.diagnose.features import MIN_TRAVEL, cycle_features
from cellguard.embodiment import Profile
from cellguard.robot.arm_cell import ArmPickPlace
from cellguard.robot.state import State

PROFILE = ArmPickPlace().profile


def _profile(dof: int) -> Profile:
    """The arm's profile cut to its first ``dof`` joints (the features read only the joint names)."""
    class Cut:
        joint_names = PROFILE.joint_names[:dof]
    return Cut()


def _reference(names, t_ns, setpoint, q, qd, effort, current, outcome) -> dict[str, float]:
    """Today's features over whole arrays, written out plainly: masks and means over every row."""
    n, f = len(t_ns), {}
    error = setpoint - q
    for j, name in enumerate(names):
        f[f"current_peak.{name}"] = float(np.abs(current[:, j]).max()) if n else 0.0
        f[f"current_rms.{name}"] = float(np.sqrt(np.mean(current[:, j] ** 2))) if n else 0.0
        f[f"tracking_rms.{name}"] = float(np.sqrt(np.mean(error[:, j] ** 2))) if n else 0.0
        f[f"tracking_max.{name}"] = float(np.abs(error[:, j]).max()) if n else 0.0
    if n:
        travel, work = np.abs(qd).sum(axis=0), (effort * qd).sum(axis=0)
        dt = (t_ns[-1] - t_ns[0]) * 1e-9 / max(n - 1, 1)
        for j, name in enumerate(names):
            if travel[j] * dt >= MIN_TRAVEL:
                f[f"friction_torque.{name}"] = float(work[j] / travel[j])
        t = (t_ns - t_ns[0]) * 1e-9
        carry = (t >= outcome["grasp_time_s"]) & (t < outcome["release_time_s"])
        if carry.sum() >= 2 and (~carry).sum() >= 2:
            for j, name in enumerate(names):
                f[f"current_carry_rms.{name}"] = float(np.sqrt(np.mean(current[carry, j] ** 2)))
                f[f"current_free_rms.{name}"] = float(np.sqrt(np.mean(current[~carry, j] ** 2)))
    return f


def _rows(n: int, dof: int, seed: int, ordered: bool = True) -> tuple[np.ndarray, ...]:
    """``n`` ticks of random data: stamps 1 ms apart with jitter (``ordered``), or in any order."""
    rng = np.random.default_rng(seed)
    t_ns = 5_000_000_000 + np.cumsum(rng.integers(500_000, 1_500_000, n))
    if not ordered:
        t_ns = rng.permutation(t_ns)
    setpoint, q, qd, effort, current = (rng.standard_normal((n, dof)) * rng.uniform(0.01, 3.0) for _ in range(5))
    return t_ns, setpoint, q, qd, effort, current


def _buffer(rows, capacity: int) -> CycleBuffer:
    t_ns, setpoint, q, qd, effort, current = rows
    buffer = CycleBuffer(setpoint.shape[1], capacity)
    for k in range(len(t_ns)):
        buffer.add(setpoint[k], setpoint[k], State(int(t_ns[k]), q[k], qd[k], effort[k], current[k]))
    return buffer


def _same(got: dict, expected: dict) -> None:
    assert set(got) == set(expected)
    for key, value in expected.items():
        assert got[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key


@settings(max_examples=60, deadline=None)
@given(n=st.one_of(st.sampled_from([0, 1, 2, 511, 512, 513, 1024, 1536, 2047]), st.integers(0, 2600)),
       dof=st.integers(1, 6), capacity=st.integers(1, 3000), seed=st.integers(0, 2 ** 32 - 1),
       window=st.tuples(st.floats(-0.1, 3.0), st.floats(-0.1, 3.0)), ordered=st.booleans())
def test_features_equal_the_whole_array_computation(n, dof, capacity, seed, window, ordered):
    """Any length (none, one tick, within a block, whole blocks, past the capacity it started with), joint count,
    carry window (empty, whole, cut anywhere) and stamp order."""
    rows = _rows(n, dof, seed, ordered)
    outcome = {"grasped": True, "grasp_time_s": min(window), "release_time_s": max(window)}
    names = _profile(dof).joint_names
    expected = {**_reference(names, *rows, outcome), "grasp_time_s": outcome["grasp_time_s"],
                "release_time_s": outcome["release_time_s"], "grasped": 1.0}
    got = cycle_features(_profile(dof), _buffer(rows, capacity), outcome, [], [])
    _same({k: v for k, v in got.items() if "." in k or k in expected}, expected)


def test_a_buffer_cleared_for_the_next_cycle_folds_its_rows_anew():
    first, second = _rows(1700, 3, 1), _rows(900, 3, 2)
    buffer = _buffer(first, 4000)
    buffer.clear()
    t_ns, setpoint, q, qd, effort, current = second
    for k in range(len(t_ns)):
        buffer.add(setpoint[k], setpoint[k], State(int(t_ns[k]), q[k], qd[k], effort[k], current[k]))
    outcome = {"grasped": True, "grasp_time_s": 0.2, "release_time_s": 0.6}
    got = cycle_features(_profile(3), buffer, outcome, [], [])
    _same({k: v for k, v in got.items() if "." in k}, _reference(_profile(3).joint_names, *second, outcome))


@pytest.mark.parametrize("n", [3 * 512 + 100, 40 * 512 + 7])
def test_the_end_reads_only_the_rows_after_the_last_whole_block_and_the_carry_windows_edge_blocks(n):
    """The rows of every whole block outside the carry window's two edge blocks are overwritten with garbage once
    added: the features are still those of the data (the end read their sums, folded as they came, not them), and
    the rows folded at the end are fewer than one block."""
    from cellguard.diagnose.cycle_buffer import BLOCK

    rows = _rows(n, 4, 3)
    buffer = _buffer(rows, n)
    outcome = {"grasped": True, "grasp_time_s": 0.3, "release_time_s": 1.1}
    t = (rows[0] - rows[0][0]) * 1e-9
    edges = {int(np.searchsorted(t, outcome[k])) // BLOCK for k in ("grasp_time_s", "release_time_s")}
    whole = n - n % BLOCK
    for k in range(whole // BLOCK):
        if k not in edges:
            for name in ("setpoint", "q", "qd", "effort", "current"):
                buffer.block(name, k)[:] = np.nan
    expected = _reference(_profile(4).joint_names, *rows, outcome)
    got = cycle_features(_profile(4), buffer, outcome, [], [])
    _same({k: v for k, v in got.items() if "." in k}, expected)
    assert buffer.fold_rest() == n % BLOCK < BLOCK
