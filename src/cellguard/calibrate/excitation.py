"""A persistently exciting trajectory as a policy source, run through the normal guarded tick path.

Each arm joint follows a Fourier series ``q0 + fade(t) * sum_k a_k sin(2 pi k f0 t + phi_k)``:
harmonics of one base frequency, Schroeder-like phases (a low peak for the power they carry),
amplitudes scaled per joint so position, velocity, acceleration and jerk stay inside
``MARGIN`` of the profile's limits (the fade-in at the start included). Being an ordinary
policy, the envelope checks every chunk it emits, so excitation is as safe as any policy.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cellguard.errors import ScenarioError
from cellguard.policy.chunk import ActionChunk
from cellguard.policy.protocol import Policy, behaviour_hash
from cellguard.robot.state import Observation
from cellguard.scenario import CycleSettings, Scenario

MARGIN = 0.5  # fraction of each profile limit the excitation may use
BASE_HZ = 0.1  # base frequency of the series [Hz]
HARMONICS = (1, 2, 3, 5, 8)  # harmonics of BASE_HZ each joint carries
MAX_SPAN = 0.6  # largest excursion of a joint from its start pose [rad] (keeps the tool off the table)
FADE_S = 2.0  # the series fades in over this long from the start pose [s]


class ExcitationPolicy(Policy):
    """Targets of a Fourier series per joint around ``q0`` (D,); joints in ``hold`` stay at ``q0``.

    ``amplitude`` (D, K) [rad or m] per joint and harmonic; ``phase`` (D, K) [rad]. Built by
    ``for_profile``, which fits the amplitudes inside the limits.
    """

    source = "excite"

    def __init__(self, q0: np.ndarray, amplitude: np.ndarray, phase: np.ndarray, horizon: int = 25,
                 dt: float = 0.02):
        self.q0, self.amplitude, self.phase = (np.asarray(a, dtype=np.float64) for a in (q0, amplitude, phase))
        self.omega = 2.0 * np.pi * BASE_HZ * np.asarray(HARMONICS, dtype=np.float64)  # (K,) [rad/s]
        self.horizon, self.dt_ns = horizon, round(dt * 1e9)
        self._t0_ns: int | None = None

    @classmethod
    def for_profile(cls, profile, q0: np.ndarray, hold: tuple[str, ...] = (), seed: int = 0) -> ExcitationPolicy:
        """Amplitudes for ``profile``'s joints around ``q0``, inside ``MARGIN`` of every limit."""
        q0 = np.asarray(q0, dtype=np.float64)
        k = np.asarray(HARMONICS, dtype=np.float64)
        omega = 2.0 * np.pi * BASE_HZ * k
        rng = np.random.default_rng(seed)
        d = profile.dof
        phase = np.pi * k * (k - 1) / len(k) + rng.uniform(0, 2 * np.pi, (d, 1))  # Schroeder phases, shifted per joint
        shape = 1.0 / k  # a falling spectrum: the fast harmonics carry less amplitude
        room = np.minimum(q0 - profile.q_min, profile.q_max - q0)  # position room either side of q0
        amplitude = np.zeros((d, len(k)))
        for i, name in enumerate(profile.joint_names):
            if name in hold:
                continue
            # bounds on the scale s of s * shape: sum |a| w^n <= margin * limit_n, n = 0..3;
            # the fade-in (a smooth step over FADE_S) at most doubles the peak rates: halve them
            sums = [shape.sum(), (shape * omega).sum() * 2, (shape * omega**2).sum() * 4, (shape * omega**3).sum() * 8]
            limits = [min(room[i], MAX_SPAN), profile.joints[i].velocity, profile.joints[i].acceleration,
                      profile.joints[i].jerk]
            amplitude[i] = min(MARGIN * lim / s for lim, s in zip(limits, sums)) * shape
        return cls(q0, amplitude, phase)

    def reset(self) -> None:
        self._t0_ns = None

    def content_hash(self) -> str:
        return behaviour_hash(self, self.q0, self.amplitude, self.phase, self.horizon, self.dt_ns)

    def at(self, t: np.ndarray) -> np.ndarray:
        """Targets (len(t), D) at times ``t`` [s] since the episode start."""
        t = np.asarray(t, dtype=np.float64)[:, None, None]
        u = np.clip(t[:, :, 0] / FADE_S, 0.0, 1.0)
        fade = u**3 * (10 - 15 * u + 6 * u * u)  # minimum-jerk smooth step
        series = (self.amplitude[None] * np.sin(self.omega * t + self.phase[None])).sum(axis=2)
        return self.q0[None] + fade * series

    def infer(self, observation: Observation) -> ActionChunk:
        if self._t0_ns is None:
            self._t0_ns = observation.t_ns
        t = (observation.t_ns - self._t0_ns + (np.arange(self.horizon) + 1) * self.dt_ns) * 1e-9
        return ActionChunk(actions=self.at(t), t_obs_ns=observation.t_ns, dt_ns=self.dt_ns)


def excitation_scenario(cell_or_scenario: str | Scenario, seconds: float, seed: int = 0) -> Scenario:
    """One episode of ``seconds``, its end by time, on a registered cell (by name) or on a scenario's
    robot (its guard settings and seed kept; its policy and cycles dropped). A scenario with faults or process
    changes is refused: they are set for its cycles, not for the excitation's one, and dropped silently the fit
    would report the robot without them while the user thinks it has them."""
    base = Scenario(cell=cell_or_scenario, seed=seed) if isinstance(cell_or_scenario, str) else cell_or_scenario
    given = [key for key in ("faults", "process_changes") if getattr(base, key)]
    if given:
        where = f"{base._path}: " if base._path else ""  # the file it was read from, as a scenario refusal names
        raise ScenarioError(f"{where}{', '.join(given)}: an excitation injects none (they are set for the scenario's "
                            "cycles) and would record the robot without them; give a scenario without them")
    return base.model_copy(update={"policy": "excite", "acceptance_cycles": 1, "production_cycles": 0,
                                   "cycle": CycleSettings(source="time", seconds=seconds)})


def excite(scenario: Scenario, out: Path, physics=None, overwrite: bool = False, stand=None) -> dict:
    """Run the excitation on ``scenario``'s robot through the guarded loop and record it in ``out``.

    ``physics``: a ``robot.physics.Physics`` applied to a simulated cell after it is built (the
    ground truth a fit must find; the record does not carry it). ``stand``: a ``calibrate.stand.Stand``
    that holds a simulated legged cell's body (the record says so). Returns the run summary.
    """
    from cellguard.record.writer import RecordConfig
    from cellguard.runtime.build import make_robot
    from cellguard.runtime.loop import Run, run_scenario

    probe = make_robot(scenario)
    policy = ExcitationPolicy.for_profile(probe.profile, _start_pose(probe), hold=_held(probe), seed=scenario.seed)
    run = Run(scenario, policy_factory=lambda: policy)
    if physics is not None:
        physics.apply(run.cell)
    if stand is not None:
        stand.apply(run.cell)
    every_tick = RecordConfig(decimated_hz=1e9 / run.cell.dt_ns)  # identification needs the full rate
    return run_scenario(scenario, out, run=run, overwrite=overwrite, record=every_tick)


def _start_pose(cell) -> np.ndarray:
    home = getattr(cell, "q_home", None)
    return np.asarray(home if home is not None else cell.read().q, dtype=np.float64)


def _held(cell) -> tuple[str, ...]:
    """Joints the excitation leaves alone: grippers (slide joints) and tool axes not in a dynamic model."""
    return tuple(j.name for j in cell.profile.joints if j.kind != "hinge")
