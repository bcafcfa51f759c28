"""Baseline, drift monitors and the diagnosis on synthetic cycles (fast, exact properties)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellguard.diagnose import Baseline, DriftConfig, as_cycles, diagnose
from cellguard.diagnose.feature_kinds import scale_floor
from cellguard.errors import RecordError

NAMES = ("grasp_tcp_x_mm", "current_rms.elbow", "tracking_rms.elbow", "latency_mean_ms", "cycle_time_s")
CENTRE = np.array([300.0, 0.41, 0.0133, 10.0, 4.444])
SIGMA = np.array([0.2, 0.002, 1e-4, 0.0, 0.0])


def rows(n: int, seed: int, start: int = 0, phase: str = "production", shift: dict | None = None,
         from_cycle: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        x = CENTRE + SIGMA * rng.standard_normal(len(NAMES))
        f = dict(zip(NAMES, x.tolist()))
        if shift and start + i >= from_cycle:
            for k, v in shift.items():
                f[k] += v
        f["grasped"] = 1.0
        out.append({"cycle": start + i, "phase": phase, "success": True, "features": f})
    return out


def record(seed: int, production: int = 60, **kw) -> list[dict]:
    return rows(20, seed, 0, "acceptance") + rows(production, seed + 1000, 20, "production", **kw)


def test_baseline_is_robust_and_floored():
    acc = as_cycles(rows(20, 1, phase="acceptance"))
    acc[3] = as_cycles([{**rows(1, 2, 3)[0], "features": {**acc[3].features, "grasp_tcp_x_mm": 900.0}}])[0]
    b = Baseline.from_cycles(acc)
    assert abs(b.median("grasp_tcp_x_mm") - 300.0) < 0.2  # one wild cycle does not move the median
    assert b.scale("latency_mean_ms") == scale_floor("latency_mean_ms", 10.0) == 1.0  # constant: the floor
    assert b.scale("current_rms.elbow") >= 0.01


def test_baseline_round_trips_and_rejects_malformed(tmp_path):
    b = Baseline.from_cycles(as_cycles(rows(20, 1, phase="acceptance")))
    b.save(tmp_path / "baseline.json")
    back = Baseline.load(tmp_path / "baseline.json")
    assert back.names == b.names and back.motions == b.motions
    (tmp_path / "bad.json").write_text('{"names": ["a"], "motions": {"": {"n": 3}}}')
    with pytest.raises(RecordError, match="baseline: malformed"):
        Baseline.load(tmp_path / "bad.json")
    with pytest.raises(RecordError, match="at least 5"):
        Baseline.from_cycles(as_cycles(rows(3, 1, phase="acceptance")))


def test_cusum_threshold_follows_siegmund_by_monte_carlo():
    """The in-control run length the threshold is set for is what a simulated CUSUM shows."""
    k, h = 1.0, 2.0
    cfg = DriftConfig(k=k)
    rng = np.random.default_rng(0)
    runs, s, length, alive = 4000, np.zeros(4000), np.zeros(4000), np.ones(4000, dtype=bool)
    while alive.any():
        s = np.where(alive, np.maximum(0.0, s + rng.standard_normal(runs) - k), s)
        length += alive
        alive &= s <= h
    from cellguard.diagnose.drift import _siegmund_arl
    assert abs(length.mean() / _siegmund_arl(h, k) - 1.0) < 0.15
    assert cfg.cusum_threshold(100) > cfg.cusum_threshold(10)  # more features, higher bar each
    assert DriftConfig(set_arl=1e6).cusum_threshold(10) > cfg.cusum_threshold(10)


@settings(max_examples=25, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10_000))
def test_no_alarm_on_a_stationary_process(seed):
    d = diagnose(record(seed, production=200), [], {})
    assert d.drift.alarms == () and d.findings == ()


@settings(max_examples=25, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10_000), sigmas=st.floats(15.0, 100.0), sign=st.sampled_from([-1.0, 1.0]))
def test_a_persistent_step_alarms_on_its_second_cycle(seed, sigmas, sign):
    step = sign * sigmas * 0.2  # grasp_tcp_x_mm scale is about 0.2 mm
    d = diagnose(record(seed, shift={"grasp_tcp_x_mm": step}, from_cycle=40), [], {})
    first = [a for a in d.drift.alarms if a.signal == "grasp_tcp_x_mm"]
    assert first and first[0].cycle == 41 and first[0].onset <= 40  # noise may start the sum early
    assert first[0].direction == (1 if sign > 0 else -1)


def test_one_odd_cycle_is_not_drift():
    data = record(4)
    data[50]["features"]["grasp_tcp_x_mm"] += 50.0
    assert diagnose(data, [], {}).drift.alarms == ()


def test_currents_of_a_cycle_with_another_load_are_not_compared():
    data = record(5, shift={"current_rms.elbow": -0.05}, from_cycle=40)
    for r in data[40:]:
        r["features"]["grasped"] = 0.0  # the part was dropped: less current, but not a friction change
    d = diagnose(data, [], {})
    assert not any(a.signal.startswith("current_") for a in d.drift.alarms)
    assert any(a.signal == "grasped" for a in d.drift.alarms)


def test_friction_pattern_is_named_with_its_joint_and_changes_listed_in_order():
    d = diagnose(record(6, shift={"current_rms.elbow": 0.06, "tracking_rms.elbow": 1e-4}, from_cycle=45), [], {})
    assert [(f.cause, f.joints) for f in d.findings] == [("friction", ("elbow",))]
    assert d.first_faulted_cycle == 45 and d.last_good_cycle == 44
    assert d.changes[0].signal == "current_rms.elbow" and d.changes[0].scales > 5
    out = d.to_dict()
    for key in ("cycles", "baseline_cycles", "last_good_cycle", "first_faulted_cycle", "drift_alarms",
                "findings", "safety_events"):
        assert key in out
    assert {"signal", "cycle", "statistic"} <= set(out["drift_alarms"][0])
    assert {"cause", "cycle", "confidence", "evidence"} <= set(out["findings"][0])


def test_policy_output_comes_from_rejected_chunks_and_events_are_listed():
    data = record(7)
    data[30]["features"]["chunks_rejected"] = 1.0
    t = int(sum(r["features"]["cycle_time_s"] for r in data[:30]) * 1e9) + 1_000_000
    events = [{"t_ns": t, "kind": "chunk_rejected", "reason": "non-finite action"},
              {"t_ns": t + 5, "kind": "chunk_steps_dropped", "reason": "stale"}]
    d = diagnose(data, events, {})
    assert [(f.cause, f.cycle) for f in d.findings] == [("policy_output", 30)]
    assert [e["kind"] for e in d.safety_events] == ["chunk_rejected"] and d.safety_events[0]["cycle"] == 30


def test_a_record_without_production_is_refused():
    with pytest.raises(RecordError, match="no production cycles"):
        diagnose(rows(20, 1, phase="acceptance"), [], {})
