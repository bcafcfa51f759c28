"""Start-up checks refuse to move with one line naming the dimension; transitions never jump."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from cellguard.control.settings import build_guard
from cellguard.policy.chunk import ActionChunk
from cellguard.robot.registry import make_cell
from cellguard.robot.state import Observation
from cellguard.runtime import Run
from cellguard.runtime.startup import StartupRefused, check_startup
from cellguard.runtime.transitions import Transition
from cellguard.scenario import parse_scenario

MS = 1_000_000  # a 1 kHz robot's servo period [ns]


class _WithStats:
    """A policy that offers LeRobot/openpi-style normalisation statistics (q01, q99) per observation key."""

    def __init__(self, policy, stats):
        self._policy, self._stats, self.source = policy, stats, "test:with-stats"

    def normalisation_stats(self):
        return self._stats

    def reset(self):
        self._policy.reset()

    def content_hash(self):
        return self._policy.content_hash()

    def infer(self, observation):
        return self._policy.infer(observation)


def _obs(q):
    return Observation(0, np.asarray(q, dtype=np.float64), np.zeros(len(q)), {"part_in_camera": np.array([0.1, 0.2, 1.0])})


def _chunk(h=25, dt_ms=20):
    return ActionChunk(np.zeros((h, 3)), 0, dt_ms * 1_000_000)


def test_an_observation_outside_the_statistics_is_refused_naming_the_dimension():
    stats = {"q": (np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0]))}
    policy = _WithStats(None, stats)
    check_startup(policy, _obs([0.5, 1.1, -0.9]), _chunk(), 10_000_000, MS)  # 1.1 is inside the 10 % margin
    with pytest.raises(StartupRefused, match=r"observation q\[2\] = -1.5 .* not moving"):
        check_startup(policy, _obs([0.5, 0.0, -1.5]), _chunk(), 10_000_000, MS)
    camera = {"part_in_camera": (np.array([0.0, 0.0, 0.0]), np.array([0.05, 0.5, 2.0]))}
    with pytest.raises(StartupRefused, match=r"part_in_camera\[0\]"):
        check_startup(_WithStats(None, camera), _obs([0, 0, 0]), _chunk(), 10_000_000, MS)


_ONES = np.ones(3)


@pytest.mark.parametrize(("stats", "message"), [
    ({"q": (np.array([-1.0, np.nan, -1.0]), _ONES)}, r"statistics for q: q01\[1\] = nan is not finite"),
    ({"q": (-_ONES, np.array([1.0, 1.0, np.inf]))}, r"statistics for q: q99\[2\] = inf is not finite"),
    ({"q": (-_ONES[:2], _ONES[:2])}, r"statistics for q: q01 has 2 values, the observation q has 3"),
    ({"q": (-_ONES, np.ones(4))}, r"statistics for q: q99 has 4 values, the observation q has 3"),
    ({"q": (_ONES * 1.2, _ONES * -1.2)}, r"statistics for q: q01\[0\] = 1.2 is above q99\[0\] = -1.2"),
    ({"q": ("low", "high")}, r"statistics for q: expected a pair \(q01, q99\) of number arrays"),
    ({"q": (-_ONES, _ONES, _ONES)}, r"statistics for q: expected a pair"),
    ({"lidar": (np.array([np.nan]), _ONES[:1])}, r"statistics name 'lidar', which the cell does not observe "
                                                 r"\(it observes: q, part_in_camera\)"),
    ({"observation.environment_state": (-_ONES, _ONES)}, r"name 'observation.environment_state', which the cell"),
    ([("q", (-_ONES, _ONES))], r"statistics must map names to \(q01, q99\), got list"),
])
def test_statistics_that_are_not_finite_ordered_or_the_observations_size_are_refused_naming_them(stats, message):
    """NaN statistics passed (NaN compares false), the wrong length was a bare ValueError, q01 > q99 an
    inverted range in the message."""
    with pytest.raises(StartupRefused, match=message + ".*not moving"):
        check_startup(_WithStats(None, stats), _obs([0.0, 0.0, 0.0]), _chunk(), 10_000_000, MS)


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_statistics_as_wide_as_the_float_range_pass_without_an_overflow_warning():
    check_startup(_WithStats(None, {"q": (-_ONES * 1e308, _ONES * 1e308)}), _obs([0.0, 0.0, 0.0]), _chunk(),
                  10_000_000, MS)


def test_a_latency_the_chunk_cannot_cover_is_refused():
    # the next observation 241 ms in (one request at a time), its chunk 241 ms later: 482 < 500
    check_startup(object(), None, _chunk(h=25, dt_ms=20), 240_000_000, MS)
    with pytest.raises(StartupRefused, match="latency 250 ms plus one servo period 1 ms .* does not fit the chunk: "
                                             "the next one, asked for 251 ms after this one's observation .* would "
                                             "arrive 502 ms after it, past its horizon 500 ms"):
        check_startup(object(), None, _chunk(h=25, dt_ms=20), 250_000_000, MS)


def test_a_run_with_an_out_of_distribution_observation_does_not_move():
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0}))
    q0 = run.cell.read().q
    lo = q0 + 0.5  # the statistics of a robot whose joints sat half a radian away
    run.policy = _WithStats(run.policy, {"q": (lo, lo + 0.01)})
    with pytest.raises(StartupRefused, match=r"observation q\[0\]"):
        run.cycle()
    assert np.abs(run.cell.read().q - q0).max() < 1e-3  # nothing moved


def _limits_ok(profile, setpoints, dt):
    v = np.diff(setpoints, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    return (np.abs(v) <= profile.array("velocity") * 1.001 + 1e-9).all() and \
        (np.abs(a) <= profile.array("acceleration") * 1.01 + 1e-6).all()


def test_a_transition_respects_the_profile_limits_and_ends_on_target():
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0}))
    profile, q0 = run.cell.profile, run.cell.read().q
    target = q0 + np.array([0.6, -0.3, 0.4, 0.0, 0.5, -0.005])
    plan = Transition.plan(profile, q0, target, 1_000_000)
    points = np.array([q0, *plan.setpoints()])
    assert np.allclose(points[-1], target, atol=1e-9)
    assert _limits_ok(profile, points, 1e-3)
    assert Transition.plan(profile, q0, q0 + 0.001, 1_000_000) is None  # already there: no transition


def test_a_robot_away_from_the_first_target_is_approached_first_and_the_cycle_still_works():
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 3, "acceptance_cycles": 1, "production_cycles": 0}))
    cell = run.cell
    q = cell.q_home + np.array([0.3, 0.2, -0.3, 0.0, 0.0, 0.0])
    cell.data.qpos[cell.drives.qadr] = q
    cell.write(q)
    mujoco.mj_forward(cell.model, cell.data)
    run.guard = build_guard(cell, run.scenario.guard)  # as at a start there: the guard holds the measured pose
    outcome = run.cycle()
    kinds = [e.kind for e in run.events]
    assert kinds[:2] == ["approach_begin", "approach_done"], kinds
    assert outcome["success"]
    assert "watchdog_stop" not in kinds


def test_a_short_chunk_is_refused_once_its_successor_would_arrive_past_it():
    check_startup(object(), None, _chunk(h=10, dt_ms=20), 90_000_000, MS)  # 200 ms chunk: 91 + 91 ms
    with pytest.raises(StartupRefused, match="would arrive 202 ms after it, past its horizon 200 ms"):
        check_startup(object(), None, _chunk(h=10, dt_ms=20), 100_000_000, MS)


class _Constant:
    """A policy that answers every observation with the pose ``q``, held for 25 steps of 20 ms."""

    source = "test:constant"

    def __init__(self, q):
        self.q = np.asarray(q, dtype=np.float64)

    def reset(self):
        pass

    def content_hash(self):
        return "0" * 64

    def infer(self, observation):
        return ActionChunk(np.tile(self.q, (25, 1)), observation.t_ns, 20_000_000)


def test_a_first_target_outside_the_workspace_box_is_refused_and_nothing_is_approached():
    """The approach is played outside the ticks' checks: it drove the tool 9 cm above the cell's box and
    left it there."""
    above = np.array([0.0, -0.3, 0.5, 0.5, 0.0, 0.025])  # tool point about 0.64 m up; the box ends at 0.55
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0}),
              policy_factory=lambda: _Constant(above))
    box = run.guard.envelope.config.box
    assert run.cell.tool_point(above)[2] > box[1][2]
    home = run.cell.read().q
    run.cycle()
    kinds = [e.kind for e in run.events]
    assert "approach_begin" not in kinds and kinds.count("chunk_rejected") >= 2
    rejected = next(e for e in run.events if e.kind == "chunk_rejected")
    assert rejected.reason.startswith("first target: its tool point [") and "outside the workspace box" in rejected.reason
    assert "watchdog_no_first_chunk" in kinds
    assert np.abs(run.cell.read().q - home).max() < 0.01  # never moved towards it


def test_an_approach_ends_inside_the_soft_limits():
    """Clipped only into the hard limits, an approach ended past the soft ones, where the guard never goes."""
    cell = make_cell("arm-pick-place")
    beyond = cell.q_home.copy()
    beyond[0] = cell.profile.q_max[0]  # shoulder_pan at its hard limit
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 1, "production_cycles": 0}),
              policy_factory=lambda: _Constant(beyond))
    soft_max, write, written = run.guard.envelope.tracker.hi[0], run.cell.write, []
    run.cell.write = lambda q: written.append(q[0]) or write(q)
    run.cycle()
    assert "approach_done" in [e.kind for e in run.events]
    assert soft_max < cell.profile.q_max[0] and max(written) <= soft_max + 1e-9


def test_a_transition_brakes_from_any_of_its_steps():
    """In the last tens of ms of a transition, ruckig raised (time synchronisation) for a brake: the run crashed
    and the setpoints stopped dead."""
    cell = make_cell("arm-pick-place", seed=1)
    start = np.array([2.095517200676611, -0.3881979234811377, -1.6090432700831832, 1.5197934259025714,
                      2.197848270666083, 0.007525704337641849])  # an approach where it raised, to the last digit
    plan = Transition.plan(cell.profile, start, np.array([2.4, -1.728, -2.4, -2.016, 2.784, 0.02854]), cell.dt_ns)
    steps = int(np.ceil(plan.duration_s * 1e9 / cell.dt_ns))
    for k in range(steps - 40, steps):
        brake = plan.brake(cell.profile, k)
        moving = np.abs(plan.state_at(k * cell.dt_ns * 1e-9)[1]).max() > 1e-9
        assert brake is not None or not moving, k


def test_a_retreat_from_a_cycle_that_ended_mid_motion_brakes_first_under_the_limits():
    """A fixed-time cycle ends while the arm moves: the retreat planned from rest stopped the command dead
    (156 times the acceleration limit in one tick)."""
    run = Run(parse_scenario({"cell": "arm-pick-place", "seed": 7, "acceptance_cycles": 1, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 2.45}}))
    write, written = run.cell.write, []
    run.cell.write = lambda q: written.append(np.array(q)) or write(q)
    run.run_cycles()
    kinds = [e.kind for e in run.events]
    assert "retreat_done" in kinds
    begin = next(e.t_ns for e in run.events if e.kind == "retreat_begin")
    assert begin == round(2.45e9)  # the cycle ended mid-motion ...
    points = np.array(written)
    assert np.abs(np.diff(points[-800:], axis=0)).max() > 1e-4  # ... and the retreat moved the arm
    assert _limits_ok(run.cell.profile, points, run.cell.dt_ns * 1e-9)
    assert np.allclose(points[-1], run.cell.q_home, atol=1e-9)


def test_a_first_chunk_during_a_category_0_stop_is_not_approached_and_the_next_cycle_starts_after_the_reset():
    """The no-first-chunk watchdog removed power; the late first chunk was approached anyway (unpowered drives
    commanded 0.5 rad away) and the approach's new guard forgot the stop."""
    away = make_cell("arm-pick-place").q_home + np.array([0.3, 0, 0, 0, 0, 0])
    run = Run(parse_scenario({"cell": "arm-pick-place", "acceptance_cycles": 2, "production_cycles": 0,
                              "cycle": {"source": "time", "seconds": 1.5},
                              "guard": {"watchdog_s": 0.1, "watchdog_category": 0},
                              "faults": [{"kind": "policy_latency", "at_cycle": 0, "until_cycle": 0, "ms": 400}]}),
              policy_factory=lambda: _Constant(away))
    first = run.cycle()
    kinds = [e.kind for e in run.events]
    assert kinds[:3] == ["watchdog_no_first_chunk", "protective_stop", "power_removed"], kinds
    assert "approach_begin" not in kinds and not run.guard.power
    held = next(e for e in run.events if e.kind == "chunk_rejected")
    assert "category 0 stop is in force" in held.reason
    assert not first["success"]
    run.cycle()
    kinds = [e.kind for e in run.events]
    assert kinds.count("reset") == 1 and "approach_done" in kinds
    assert kinds.index("reset") < kinds.index("approach_begin")
    assert kinds.count("watchdog_no_first_chunk") == 1  # the watchdog runs again from the reset, and was fed
