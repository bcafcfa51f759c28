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

Each coefficient is scored against the windows before it of the same motion (a mirrored cell's
``left`` and ``right`` cycles, ``diagnose.cycles.LABELS``, differ in their residual as in their motion):
its error against a forecast (an EWMA of the earlier windows, weight ``FORECAST``) over the spread of
the earlier forecast errors, Student-t with as many degrees of freedom as errors, mapped through its
CDF onto a standard normal score. Why a forecast and not a fixed baseline mean: a fault-free residual
wanders slowly (the quadruped's posture drifts over tens of turns and its joint model has no foot
forces; the arm's grasp varies), and a CUSUM sums serially correlated deviations into false alarms;
the one-step forecast errors of such a series are close to independent (the special-cause chart for
autocorrelated data), which is what the threshold's design assumes. Why Student-t: ten baseline
windows (the acceptance cycles) give a spread that is below 0.7 of the true one one time in ten; the
t score says how far a value is given what is known, and it sharpens as fault-free windows come in.

Each score feeds a two-sided CUSUM (reference value ``K``) whose threshold ``h`` is derived, not
tuned: the whole monitor (every joint, signature and direction together) has a design false-alarm
rate of one alarm per ``SET_ARL`` fault-free windows (``diagnose.drift``'s Siegmund design, each of
the ``2 nj S`` one-sided CUSUMs given ``2 nj S x SET_ARL``). A score is capped at ``h / 2 + K +
0.25``: one odd window (a grasp that slips, an impact) cannot alarm by itself, a change that
persists alarms on its second window. A capped window is held out of the running mean and spread,
so a change is never learnt as normal. An alarm names the joint and the likely parameter (inertia
and payload are reported together as ``inertia/payload``). The window's summary is a plain dict:
the run stores it in the cycle's outcome (``outcome["residual"]``), where diagnosis reads it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from cellguard.calibrate.torque_model import MIN_SPEED, JointTerms, TorqueModel, inverse_torques, rigid_model
from cellguard.diagnose.cycles import LABELS
from cellguard.diagnose.drift import DriftConfig
from cellguard.errors import ScenarioError

SIGNATURES = ("friction", "inertia", "payload", "delay")
LIKELY = {"friction": "friction", "inertia": "inertia/payload", "payload": "inertia/payload", "delay": "delay"}
UNITS = {"friction": "N*m", "inertia": "kg*m^2", "payload": "kg", "delay": "s"}
BASELINE_WINDOWS = 10  # windows that only learn each coefficient's mean and spread (no CUSUM yet)
K = 1.0  # CUSUM reference value [standard normal scores]
FORECAST = 0.2  # EWMA weight of the newest window in the forecast of the next one
SET_ARL = 100_000.0  # design: fault-free windows between false alarms of the whole monitor (all joints together)
EVERY = 4  # the model is evaluated on every this-many-th tick (differences taken at the full rate)
RATE_TICKS = 5  # half-width of the central difference that gives the model torque's rate [ticks]


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
    """Windows of one cell's ticks in, alarms out; ``terms`` the model's joint terms (nominal if None).

    ``baseline``: windows that only learn (the acceptance cycles); ``set_arl``: the design's fault-free
    windows between false alarms of the whole monitor. ``threshold`` and ``cap`` follow from them."""

    cell: object
    terms: JointTerms | None = None
    baseline: int = BASELINE_WINDOWS
    set_arl: float = SET_ARL
    windows: int = 0
    drifted: set = field(default_factory=set)  # joints alarmed so far
    _learnt: dict = field(default_factory=dict)  # per motion label: see _stats
    _up: np.ndarray | None = None
    _down: np.ndarray | None = None

    def __post_init__(self):
        self.model = TorqueModel(self.cell, self.terms)
        self.signatures = tuple(s for s in SIGNATURES if s != "payload" or self._has_tool())
        self.loaded = rigid_model(self.cell.model, self.model.terms.payload_kg + 1.0) if "payload" in self.signatures \
            else None
        shape = (len(self.model.joints), len(self.signatures))
        self._shape = shape
        self._up, self._down = np.zeros(shape), np.zeros(shape)
        design = DriftConfig(k=K, set_arl=self.set_arl, banks=1)
        self.threshold = design.cusum_threshold(shape[0] * shape[1])  # h [scores]
        self.cap = design.clip(self.threshold)  # the largest score one window adds

    def _has_tool(self) -> bool:
        import mujoco

        return mujoco.mj_name2id(self.cell.model, mujoco.mjtObj.mjOBJ_BODY, "tool") >= 0

    def update(self, q: np.ndarray, qd: np.ndarray, current: np.ndarray, label: str | None = None) -> dict:
        """One window of contiguous servo-rate ticks (n, dof): its coefficients, CUSUMs and alarms (a dict).
        ``label``: the motion the window performed (``left``/``right`` on a mirrored cell); a window is
        compared with earlier windows of the same motion only."""
        window = self.windows
        self.windows += 1
        coef = self.coefficients(q, qd, current)
        out = {"window": window, "joints": list(self.model.names), "signatures": list(self.signatures),
               "coefficients": np.round(coef, 9).tolist(), "alarms": []}
        if label is not None:
            out["label"] = label
        if window < self.baseline:
            self._learn(label, coef, np.isfinite(coef))
            out["baseline"] = True
            return out
        z = self.scores(coef, label)
        zc = np.clip(z, -self.cap, self.cap)
        self._up = np.maximum(0.0, self._up + zc - K)
        self._down = np.maximum(0.0, self._down - zc - K)
        self._learn(label, coef, np.isfinite(coef) & (np.abs(z) < self.cap))  # a capped window is not learnt
        stat = np.maximum(self._up, self._down) / self.threshold
        out["cusum"] = np.round(stat, 3).tolist()
        out["drifted"] = sorted(self.drifted)
        for k in np.flatnonzero((stat >= 1.0).any(axis=1)):
            s = int(np.argmax(stat[k]))
            self._up[k], self._down[k] = 0.0, 0.0  # restart this joint's CUSUMs
            if self.model.names[k] in self.drifted:  # said once; ``identify --only`` and a new monitor clear it
                continue
            self.drifted.add(self.model.names[k])
            sig = self.signatures[s]
            forecast = self._stats(label)[1]
            alarm = ResidualAlarm(window, self.model.names[k], LIKELY[sig], sig, float(coef[k, s] - forecast[k, s]),
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

    def scores(self, coef: np.ndarray, label: str | None = None) -> np.ndarray:
        """Standard normal scores (nj, S) of ``coef``: its error against the forecast from the earlier windows
        of motion ``label``, over the spread of the ``n`` forecast errors before it (Student-t with ``n``
        degrees of freedom), through the t CDF onto N(0, 1); 0 where a coefficient is NaN or fewer than three
        errors lie behind it."""
        _, forecast, n, sse = self._stats(label)
        ok = np.isfinite(coef) & (n >= 3)
        z = np.zeros_like(coef)
        if not ok.any():
            return z
        t = (coef[ok] - forecast[ok]) / np.maximum(np.sqrt(sse[ok] / n[ok]), np.finfo(float).tiny)
        # the upper tail of each side, so a far value keeps its precision: z = -Phi^-1(P(T > |t|)) sign(t)
        z[ok] = np.sign(t) * stats.norm.isf(stats.t.sf(np.abs(t), n[ok]))
        return z

    def _stats(self, label: str | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(windows learnt, forecast, forecast errors counted, their sum of squares) per coefficient (nj, S) of
        motion ``label``."""
        if label not in self._learnt:
            self._learnt[label] = tuple(np.zeros(self._shape) for _ in range(4))
        return self._learnt[label]

    def _learn(self, label: str | None, coef: np.ndarray, use: np.ndarray) -> None:
        """Where ``use``: count ``coef``'s forecast error and move the forecast towards it (EWMA, ``FORECAST``)."""
        seen, forecast, n, sse = self._stats(label)
        scored = use & (seen > 0)
        error = np.where(scored, coef - forecast, 0.0)
        forecast = np.where(use & (seen == 0), coef, forecast + FORECAST * error)
        self._learnt[label] = (seen + use, forecast, n + scored, sse + error * error)


def watch_scenario(run) -> None:
    """The monitor a scenario's ``residual_monitor: true`` asks for, on ``run``: the model with the calibration's
    terms (else the profile's measured values over the nominal model), learning from the acceptance cycles
    (fewer than ``BASELINE_WINDOWS`` is refused: the threshold's false-alarm rate was measured from ten)."""
    scenario = run.scenario
    if not scenario.residual_monitor:
        return
    if not hasattr(run.cell, "model"):
        raise ScenarioError(f"residual_monitor: robot {scenario.robot!r} has no MuJoCo model to compare the measured "
                            "torques with (simulated cells only)")
    if scenario.acceptance_cycles < BASELINE_WINDOWS:
        raise ScenarioError(f"residual_monitor: needs acceptance_cycles >= {BASELINE_WINDOWS} (the monitor learns "
                            f"each joint's residual from them), got {scenario.acceptance_cycles}")
    terms = JointTerms.from_profile(run.cell, scenario.calibration, option="calibration")
    watch(run, ResidualMonitor(run.cell, terms, baseline=scenario.acceptance_cycles))


def watch(run, monitor: ResidualMonitor) -> None:
    """Feed ``monitor`` each cycle of ``run`` (a ``runtime.loop.Run``); the window lands in the cycle's
    outcome as ``residual`` (so in the record's cycle channel, where diagnosis reads it). ``update`` takes whole
    columns (rate differences across ticks, one least-squares fit over the window): a cycle longer than one of
    the buffer's chunks is joined here, at its end (``CycleBuffer.rows``)."""

    def window(ticks, outcome: dict) -> None:
        labels = [str(outcome[k]) for k in LABELS if isinstance(outcome.get(k), str)]
        outcome["residual"] = monitor.update(ticks.rows("q"), ticks.rows("qd"), ticks.rows("current"),
                                             "/".join(labels) if labels else None)

    run.cycle_monitors.append(window)
