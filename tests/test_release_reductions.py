"""A counted run is held reduced: the gates' figures from its chunks and ticks, never the chunks and ticks whole."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest
from release_helpers import CELL, Received

from cellguard.record.reader import open_record
from cellguard.release.evidence import load_run
from cellguard.release.metrics import METRICS
from cellguard.release.reductions import limit_ticks, reduce_chunks
from cellguard.robot.registry import make_cell
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    """Three scripted cycles on the arm: a real record with thousands of chunks and ticks."""
    out = tmp_path_factory.mktemp("reduce") / "run"
    run_scenario(parse_scenario({"cell": CELL, "seed": 3, "policy": "scripted", "acceptance_cycles": 3,
                                  "production_cycles": 0}), out)
    return out


def test_a_run_is_held_as_its_cycles_not_its_ticks_and_chunks(record):
    """A stage's gates read every run since its release became current: held whole, each cycle of a run cost
    about 230 kB (its chunks' actions and its ticks), so the evaluation's memory grew with the stage's history."""
    run = load_run(record, "r")
    with open_record(record) as rec:
        chunks, ticks = list(rec.chunks()), rec.ticks(rate="decimated")
    raw = sum(c.actions.nbytes for c in chunks) + 6 * ticks.q_meas.nbytes
    assert len(pickle.dumps(run)) < 0.1 * raw
    assert len(run.chunks.latency_ms) == len(chunks) and run.chunks.seams > 0
    assert run.chunks.latency_ms.max() == max(c.latency_ns for c in chunks) * 1e-6


def test_ticks_outside_a_narrowed_range_are_counted_with_the_first_ones_cycle_and_joint(record):
    profile = make_cell(CELL).profile
    with open_record(record) as rec:
        ticks = rec.ticks(rate="decimated")
    assert limit_ticks(ticks, profile).count == 0
    j = 1
    top = float(np.median(ticks.q_meas[:, j]))  # half the ticks above the joint's new upper limit
    narrowed = dataclasses.replace(profile, joints=tuple(
        dataclasses.replace(lim, position=(lim.position[0], top)) if i == j else lim
        for i, lim in enumerate(profile.joints)))
    limits = limit_ticks(ticks, narrowed)
    over = np.flatnonzero(ticks.q_meas[:, j] > top)
    assert limits.count == len(over) > 0
    assert (limits.first_cycle, limits.joint) == (int(ticks.cycle[over[0]]), profile.joint_names[j])


def _chunk(t_obs_ns: int, value: float, latency_ns: int = 5_000_000) -> Received:
    """Ten steps of 20 ms holding ``value`` on two joints, received ``latency_ns`` after its observation."""
    return Received(t_obs_ns, t_obs_ns + latency_ns, latency_ns, 20_000_000, np.full((10, 2), value))


def test_the_largest_seam_is_the_step_between_the_chunks_when_the_new_one_takes_over():
    a, b, c = _chunk(0, 0.0), _chunk(100_000_000, 0.003), _chunk(150_000_000, 0.0025)
    got = reduce_chunks([a, b, c])
    assert got.seams == 2
    assert got.worst_seam_mrad == pytest.approx(3.0)
    assert got.worst_seam_t_ns == b.t_obs_ns + b.dt_ns  # it arrived before its first step
    late = _chunk(10_000_000_000, 1.0)  # after the last one ended: no seam
    assert reduce_chunks([a, late]).seams == 0


class _Run:
    def __init__(self, chunks, name: str = "run"):
        self.chunks, self.cycles, self.name = chunks, (), name

    def label(self, cycle=None):
        return self.name


def test_seam_and_latency_gates_read_the_reductions():
    runs = [_Run(reduce_chunks([_chunk(0, 0.0), _chunk(100_000_000, 0.002, latency_ns=9_000_000)])),
            _Run(reduce_chunks([_chunk(0, 0.0)]))]
    seam = METRICS["chunk_seam_jump_max_mrad"].compute(runs)
    assert seam.value == pytest.approx(2.0) and "largest seam 2.0 mrad in run at t=0.120 s" in seam.evidence[0]
    latency = METRICS["inference_latency_p99_ms"].compute(runs)
    assert latency.value == pytest.approx(np.percentile([5.0, 9.0, 5.0], 99))
    assert latency.evidence == ("worst 9 ms in run",)
    assert METRICS["chunk_seam_jump_max_mrad"].compute(runs[1:]).value is None  # no seam: no data


def test_a_latency_tie_names_the_run_it_named_before():
    """The evidence goes into the hash-chained log: on equal worst latencies it names the run whose label sorts
    last, as when every chunk's latency was held whole."""
    runs = [_Run(reduce_chunks([_chunk(0, 0.0)]), "record b"), _Run(reduce_chunks([_chunk(0, 0.0)]), "record c"),
            _Run(reduce_chunks([_chunk(0, 0.0)]), "record a")]
    assert METRICS["inference_latency_p99_ms"].compute(runs).evidence == ("worst 5 ms in record c",)
