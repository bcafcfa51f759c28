"""Sim-versus-real residual monitor: has the robot drifted beyond its (calibrated) model?

Per window (one cycle of ticks) and hinge joint, the residual is the measured torque (current x
torque constant) minus the torque the model needs for the measured motion (``TorqueModel``:
``mj_inverse`` plus the joint terms). Over the window's moving samples the residual is regressed
on the signature of each kind of model error:

    friction   sign(velocity)             (its coefficient is the residual projected onto the
                                           direction of motion) [N*m]
    inertia    acceleration               [kg*m^2]
    payload    the torque 1 kg more at the tool needs (cells with a tool) [kg]
    delay      model torque's rate        (a timing offset between current and motion) [s]

Each coefficient is normalised by the mean and spread of the first ``baseline`` windows (the
acceptance cycles: what the cell does when it is known good, systematic model error included)
and fed to a two-sided CUSUM. An alarm names the joint and the likely parameter (inertia and
payload are reported together as ``inertia/payload``). The window's summary is a plain dict:
the run stores it in the cycle's outcome (``outcome["residual"]``), where diagnosis reads it.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

from cellguard.calibrate.torque_model import MIN_SPEED, JointTerms, TorqueModel, inverse_torques, rigid_model

SIGNATURES = ("friction", "inertia", "payload", "delay")
LIKELY = {"friction": "friction", "inertia": "inertia/payload", "payload": "inertia/payload", "delay": "delay"}
UNITS = {"friction": "N*m", "inertia": "kg*m^2", "payload": "kg", "delay": "s"}
BASELINE_WINDOWS = 10  # windows that set each coefficient's normal mean and spread
K = 1.0  # CUSUM allowance [baseline spreads]
H = 12.0  # CUSUM threshold [baseline spreads]: over the whole set of joints and signatures, see benchmark
EVERY = 4  # the model is evaluated on every this-many-th tick (differences taken at the full rate)
RATE_TICKS = 5  # half-width of the central difference that gives the model torque's rate [ticks]
SPREAD_FLOOR = 0.02  # a coefficient's spread is at least this fraction of its joint's scale (see _floor)


@dataclass(frozen=True)
class ResidualAlarm:
    """The robot has drifted beyond its model at ``joint``: ``parameter`` is the likely cause."""

    window: int
    joint: str
    parameter: str  # friction | inertia/payload | delay
    signature: str  # the coefficient that crossed: friction | inertia | payload | delay
    change: float  # the coefficient minus its baseline mean, in ``unit``
    unit: str
    statistic: float  # CUSUM value / threshold (>= 1)

    def describe(self) -> str:
        return (f"the robot has drifted beyond its model at {self.joint}: {self.parameter}-like residual "
                f"({self.signature} {self.change:+.3g} {self.unit} vs baseline, "
                f"CUSUM {self.statistic:.1f} x threshold)")

    def to_dict(self) -> dict:
        return {"window": self.window, "joint": self.joint, "parameter": self.parameter, "signature": self.signature,
                "change": self.change, "unit": self.unit, "statistic": self.statistic, "message": self.describe()}


@dataclass
class ResidualMonitor:
    """Windows of one cell's ticks in, alarms out; ``terms`` the model's joint terms (nominal if None)."""

    cell: object
    terms: JointTerms | None = None
    baseline: int = BASELINE_WINDOWS
    windows: int = 0
    drifted: set = field(default_factory=set)  # joints alarmed so far
    _coef: list = field(default_factory=list)  # baseline windows' coefficients (nj, S)
    _mean: np.ndarray | None = None
    _spread: np.ndarray | None = None
    _up: np.ndarray | None = None
    _down: np.ndarray | None = None

    def __post_init__(self):
        self.model = TorqueModel(self.cell, self.terms)
        self.signatures = tuple(s for s in SIGNATURES if s != "payload" or self._has_tool())
        self.loaded = rigid_model(self.cell.model, self.model.terms.payload_kg + 1.0) if "payload" in self.signatures \
            else None

    def _has_tool(self) -> bool:
        import mujoco

        return mujoco.mj_name2id(self.cell.model, mujoco.mjtObj.mjOBJ_BODY, "tool") >= 0

    def update(self, q: np.ndarray, qd: np.ndarray, current: np.ndarray) -> dict:
        """One window of contiguous servo-rate ticks (n, dof): its coefficients, CUSUMs and alarms (a dict)."""
        window = self.windows
        self.windows += 1
        coef = self.coefficients(q, qd, current)
        out = {"window": window, "joints": list(self.model.names), "signatures": list(self.signatures),
               "coefficients": np.round(coef, 9).tolist(), "alarms": []}
        if window < self.baseline:
            self._coef.append(coef)
            if window == self.baseline - 1:
                self._set_baseline()
            out["baseline"] = True
            return out
        if self._mean is None:
            return out
        z = np.nan_to_num((coef - self._mean) / self._spread)
        self._up = np.maximum(0.0, self._up + z - K)
        self._down = np.maximum(0.0, self._down - z - K)
        stat = np.maximum(self._up, self._down) / H
        out["cusum"] = np.round(stat, 3).tolist()
        out["drifted"] = sorted(self.drifted)
        for k in np.flatnonzero((stat >= 1.0).any(axis=1)):
            s = int(np.argmax(stat[k]))
            self._up[k], self._down[k] = 0.0, 0.0  # restart this joint's CUSUMs
            if self.model.names[k] in self.drifted:  # said once; ``identify --only`` and a new monitor clear it
                continue
            self.drifted.add(self.model.names[k])
            sig = self.signatures[s]
            alarm = ResidualAlarm(window, self.model.names[k], LIKELY[sig], sig, float(coef[k, s] - self._mean[k, s]),
                                  UNITS[sig], float(stat[k, s]))
            out["alarms"].append(alarm.to_dict())
        return out

    def coefficients(self, q: np.ndarray, qd: np.ndarray, current: np.ndarray) -> np.ndarray:
        """Per hinge joint, the residual's coefficient on each signature (nj, S); NaN where it barely moves."""
        m = self.model
        j = m.joints
        h = RATE_TICKS
        steps = np.arange(h, len(q) - 1 - h, EVERY)  # every EVERY-th step, with room for the rate's difference
        if len(steps) < 10 * len(self.signatures):
            return np.full((len(j), len(self.signatures)), np.nan)
        around = np.unique(np.concatenate([steps - h, steps, steps + h]))
        model_tau = m.torque(q, qd, around)
        at = {int(s): i for i, s in enumerate(around)}
        mid = model_tau[[at[int(s)] for s in steps]]
        after, before = model_tau[[at[int(s) + h] for s in steps]], model_tau[[at[int(s) - h] for s in steps]]
        rate = (after - before) / (2 * h * m.dt)
        residual = current[steps + 1][:, j] * m.torque_constant - mid
        v = qd[steps][:, j]
        columns = {"friction": np.sign(v), "inertia": (qd[steps + 1][:, j] - v) / m.dt, "delay": rate}
        if self.loaded is not None:
            columns["payload"] = inverse_torques(self.loaded, self.cell, q, qd, m.dt, steps) - inverse_torques(
                m.rigid, self.cell, q, qd, m.dt, steps)
        out = np.full((len(j), len(self.signatures)), np.nan)
        for k in range(len(j)):
            use = np.abs(v[:, k]) > MIN_SPEED
            if use.sum() < 10 * len(self.signatures):
                continue
            x = np.column_stack([columns[s][use, k] for s in self.signatures])
            out[k], *_ = np.linalg.lstsq(x, residual[use, k], rcond=None)
        return out

    def _set_baseline(self) -> None:
        coef = np.array(self._coef)
        if len(coef) < 3:
            return
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a joint that never moved: NaN, not monitored
            self._mean = np.nanmean(coef, axis=0)
            self._spread = np.maximum(np.nanstd(coef, axis=0, ddof=1), self._floor())
        self._up = np.zeros_like(self._mean)
        self._down = np.zeros_like(self._mean)

    def _floor(self) -> np.ndarray:
        """The smallest spread each coefficient is given (nj, S): ``SPREAD_FLOOR`` of the joint's dry friction,
        effective inertia, 1 kg, and one servo period; a few windows understate the spread otherwise."""
        m = self.model
        scale = {"friction": m.terms.friction, "inertia": m.inertia, "payload": np.ones(len(m.joints)),
                 "delay": np.full(len(m.joints), m.dt)}
        return SPREAD_FLOOR * np.column_stack([scale[s] for s in self.signatures])


def watch(run, monitor: ResidualMonitor) -> None:
    """Feed ``monitor`` each cycle of ``run`` (a ``runtime.loop.Run``); the window lands in the cycle's
    outcome as ``residual`` (so in the record's cycle channel, where diagnosis reads it)."""

    def window(ticks, outcome: dict) -> None:
        n = ticks.n
        keep = slice(0, n)
        outcome["residual"] = monitor.update(ticks.q[keep], ticks.qd[keep], ticks.current[keep])

    run.cycle_monitors.append(window)
