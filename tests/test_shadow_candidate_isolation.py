"""Shadow mode against a candidate that answers wrongly, and the shadow's time alignment of chunks.

A candidate whose chunk has another action dimension (or that answers None) raised inside the incumbent's
inference: the live robot saw inference_failed and a watchdog stop, and shadow.json had no row. A step of a
chunk is due at ``t_obs + (i + 1) * dt``; the shadow sampled it at ``t_obs + i * dt``, so the same motion at
20 ms and at 10 ms steps read 10 mrad apart.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from release_helpers import CELL, Received

import cellguard.release.shadow as shadow
from cellguard.control.config import GuardConfig
from cellguard.policy.chunk import ActionChunk
from cellguard.release.evidence import load_run
from cellguard.release.metrics import METRICS
from cellguard.release.reductions import action_at, reduce_chunks
from cellguard.runtime import run_scenario
from cellguard.scenario import parse_scenario


class _Wrong:
    """The taught program, each answer spoilt by ``spoil``."""

    def __init__(self, inner, spoil):
        self.inner, self.spoil, self.source = inner, spoil, "wrong"

    def reset(self):
        self.inner.reset()

    def content_hash(self):
        return "wrong"

    def close(self):
        pass

    def infer(self, observation):
        return self.spoil(self.inner.infer(observation))


def _shadow_run(tmp_path, monkeypatch, spoil):
    real = shadow.make_policy
    monkeypatch.setattr(shadow, "make_policy", lambda spec, cell, **kw: _Wrong(real(spec, cell, **kw), spoil))
    scenario = parse_scenario({"cell": CELL, "seed": 3, "policy": "scripted", "acceptance_cycles": 1,
                               "production_cycles": 0})
    run = shadow.ShadowRun(scenario, "scripted", GuardConfig())
    folder = tmp_path / "shadow"
    summary = run_scenario(scenario, folder, run=run)
    run.write_shadow(folder)
    return summary, json.loads((folder / "shadow.json").read_text())["chunks"], load_run(folder, "wrong")


@pytest.mark.parametrize(("spoil", "event"), [
    (lambda c: ActionChunk(np.asarray(c.actions)[:, :-1], c.t_obs_ns, c.dt_ns), "chunk_rejected"),  # 6 of 7 joints
    (lambda c: None, "inference_failed: TypeError"),
    (lambda c: ActionChunk(c.actions, c.t_obs_ns, 0), "chunk_rejected"),  # no step period
])
def test_a_candidate_answering_wrongly_is_its_own_would_be_stop_and_the_incumbent_drives_on(
        tmp_path, monkeypatch, spoil, event):
    summary, rows, run = _shadow_run(tmp_path, monkeypatch, spoil)
    assert summary["phases"]["acceptance"]["success_rate"] == 1.0
    assert not [e for e in summary["events"] if e["kind"] != "chunk_steps_dropped"]  # the robot saw nothing of it
    assert rows and all(event in r["events"] and r["distance_rad"] is None for r in rows)
    assert METRICS["shadow_would_stop"].compute([run]).value >= 1.0


def _ramp(dt_ns: int, horizon: int, t_obs_ns: int = 1_000_000_000) -> ActionChunk:
    """q(t) = 1 rad/s x (t - t_obs) on 7 joints, each step at its due time ``t_obs + (i + 1) * dt``."""
    due = (np.arange(horizon) + 1) * dt_ns * 1e-9
    return ActionChunk(np.repeat(due[:, None], 7, axis=1), t_obs_ns, dt_ns)


def test_the_same_motion_at_two_step_periods_is_at_zero_distance():
    assert shadow._distance(_ramp(20_000_000, 25), _ramp(10_000_000, 50)) == pytest.approx(0.0, abs=1e-12)
    assert shadow._distance(_ramp(10_000_000, 50), _ramp(20_000_000, 25)) == pytest.approx(0.0, abs=1e-12)


def test_a_chunk_step_is_read_at_its_due_time():
    chunk = _ramp(20_000_000, 25)
    due = chunk.step_times_ns()
    np.testing.assert_allclose(action_at(chunk, int(due[0])), chunk.actions[0])
    np.testing.assert_allclose(action_at(chunk, int(due[-1])), chunk.actions[-1])
    assert action_at(chunk, chunk.t_obs_ns) is None  # no target before its first step
    assert action_at(chunk, int(due[-1]) + 1) is None


class _Run:
    def __init__(self, chunks):
        self.chunks, self.cycles = reduce_chunks(chunks), ()

    def label(self, cycle=None):
        return "run"


def test_two_chunks_of_one_motion_meet_without_a_seam():
    """Each chunk a sample of one ramp; the next arrives 10 ms after its observation, before its first step."""
    a, b = _ramp(20_000_000, 25), _ramp(20_000_000, 25, t_obs_ns=1_100_000_000)
    shift = (b.t_obs_ns - a.t_obs_ns) * 1e-9  # b's ramp starts from 0 at its own observation: put it on a's
    chunks = [Received(c.t_obs_ns, c.t_obs_ns + 10_000_000, 10_000_000, c.dt_ns, np.asarray(c.actions) + s)
              for c, s in ((a, 0.0), (b, shift))]
    assert METRICS["chunk_seam_jump_max_mrad"].compute([_Run(chunks)]).value == pytest.approx(0.0, abs=1e-9)


def test_the_run_closes_the_candidate_it_built(tmp_path, monkeypatch):
    """A shadow run's policy is the incumbent with the candidate beside it: the run closed neither (an openpi
    candidate's connection stayed open till the process ended)."""
    closed = []

    class Closing(_Wrong):
        def close(self):
            closed.append(self.source)

    real = shadow.make_policy
    monkeypatch.setattr(shadow, "make_policy", lambda spec, cell, **kw: Closing(real(spec, cell, **kw), lambda c: c))
    scenario = parse_scenario({"cell": CELL, "seed": 3, "policy": "scripted", "acceptance_cycles": 1,
                               "production_cycles": 0})
    run_scenario(scenario, tmp_path / "shadow", run=shadow.ShadowRun(scenario, "scripted", GuardConfig()))
    assert closed == ["wrong"]
