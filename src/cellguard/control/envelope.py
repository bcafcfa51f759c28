"""Envelope: the last software check between the reference and the robot, once per servo tick.

Inside the envelope the reference sample is sent exactly (see ``tracker``: no filter, no
delay). Around it: soft and hard position limits with stopping-distance look-ahead; velocity,
acceleration and jerk limits; an effort limit on the measured joint efforts; a Cartesian box
for the tool point with its own look-ahead; a tool-speed cap, lowered to the reduced speed
(250 mm/s, ISO 10218-1) when the safety controller asks for it or the policy is unsure; a
watchdog on policy silence; and stops of IEC 60204-1 categories 0, 1 and 2.

Speed is lowered by slowing the executor's playback clock (``scale``), which keeps the path
and stretches time. ``scale`` moves with bounded rate and rate of rate, so the slow-down itself
stays inside the acceleration and jerk limits for a reference inside them.

This is software, not a safety-rated function: it obeys the certified safety controller's
protective-stop and reduced-speed inputs; it does not replace them.

Every intervention is an ``Event`` with its time, joint, what was asked, what was sent and
why; a lasting condition raises one event when it starts.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cellguard.control.events import Event
from cellguard.control.tracker import PASS, STOP, Tracker
from cellguard.embodiment import Profile
from cellguard.robot.protocol import SafetyInputs

NO_INPUTS = SafetyInputs()
INTERVENTION_QUIET_NS = 200_000_000  # a joint's intervention is a new event after this long untouched
REDUCED_SCALE_WITHOUT_TOOL = 0.25  # playback speed in reduced mode when no tool model gives the tool speed


@dataclass(frozen=True)
class EnvelopeConfig:
    """Settings of the envelope (SI). The profile gives the joint limits; these the rest."""

    soft_margin: float = 0.02  # soft limits this fraction of each joint's range inside the hard limits
    watchdog_s: float = 0.3  # no fresh chunk for this long -> controlled stop
    watchdog_category: int = 2
    uncertainty_threshold: float | None = None  # chunk uncertainty above it -> gate
    uncertainty_action: str = "reduce"  # "reduce" (reduced speed) or "hold" (category 2 stop until it clears)
    tool_speed_max: float | None = None  # [m/s] cap in normal operation; None: joint limits only
    reduced_speed: float = 0.25  # [m/s] tool speed in reduced-speed mode (ISO 10218-1)
    effort_fraction: float = 0.98  # measured |effort| above this fraction of the limit ...
    effort_hold_s: float = 0.05  # ... for this long -> category 2 stop (collision or jam)
    box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None  # tool point [m]
    scale_rate: float = 2.0  # [1/s] largest rate of change of the speed scale
    scale_accel: float = 40.0  # [1/s²]

    def __post_init__(self):
        if self.watchdog_category not in (0, 1, 2):
            raise ValueError(f"watchdog_category must be 0, 1 or 2, got {self.watchdog_category}")
        if self.uncertainty_action not in ("reduce", "hold"):
            raise ValueError(f"uncertainty_action must be 'reduce' or 'hold', got {self.uncertainty_action!r}")
        if not 0.0 <= self.soft_margin < 0.5:
            raise ValueError(f"soft_margin must be in [0, 0.5), got {self.soft_margin}")


class Envelope:
    """Limits, watchdog, gate and stops around a Tracker; ``apply`` once per servo tick.

    ``tool``: joint positions (D,) -> tool point (3,) [m], needed for the box and the tool-speed
    cap. ``scale`` is the speed the executor's playback clock should run at next tick.
    """

    def __init__(self, profile: Profile, q0: np.ndarray, dt_ns: int, config: EnvelopeConfig | None = None,
                 tool: Callable[[np.ndarray], np.ndarray] | None = None):
        self.profile, self.config, self.dt_ns, self._tool = profile, config or EnvelopeConfig(), int(dt_ns), tool
        c = self.config
        lo, hi = profile.q_min, profile.q_max
        margin = c.soft_margin * (hi - lo)
        self.tracker = Tracker(q0, profile.array("velocity"), profile.array("acceleration"), profile.array("jerk"),
                               lo + margin, hi - margin, dt_ns * 1e-9)
        self._effort_max = profile.array("effort") * c.effort_fraction
        self._effort_ticks = np.zeros(profile.dof, dtype=np.int64)
        self._effort_hold = max(1, round(c.effort_hold_s * 1e9 / dt_ns))
        self._box = None if c.box is None else (tuple(map(float, c.box[0])), tuple(map(float, c.box[1])))
        if self._box is not None and tool is None:
            raise ValueError("box: a tool model (forward kinematics) is needed to check the tool point")
        # tool point of the last setpoint [m], plain floats: three coordinates are cheaper so on the tick
        self._tip = None if tool is None else tuple(tool(np.asarray(q0, dtype=np.float64)).tolist())
        self._inv_a = (1.0 / profile.array("acceleration")).tolist()
        self._t_jerk = float((profile.array("acceleration") / profile.array("jerk")).max())
        self.scale, self._scale_rate = 1.0, 0.0
        self.stop_category: int | None = None  # of the stop in force
        self.stop_reason: str | None = None
        self.power = True
        self._active: set[str] = set()  # lasting conditions already reported
        self.tool_speed = 0.0  # [m/s] of the last setpoint
        self._last_intervention = np.full(profile.dof, -(2**62), dtype=np.int64)  # per joint [ns]

    # -- the tick ------------------------------------------------------------------------
    def apply(self, t_ns: int, reference: np.ndarray, state=None, safety: SafetyInputs = NO_INPUTS,
              last_chunk_ns: int | None = None, uncertainty: float = 0.0,
              tool_speed_ahead: float | None = None) -> tuple[np.ndarray, list[Event]]:
        """The setpoint (D,) for this tick and the events raised; never raises on bad values."""
        events: list[Event] = []
        tracker = self.tracker
        finite = bool(np.isfinite(reference).all())
        request = self._stop_request(t_ns, reference, finite, state, safety, last_chunk_ns, uncertainty, events)
        if request is not None:
            self._begin_stop(t_ns, *request, events)
        elif self.stop_category == 2 and tracker.stopped:
            events.append(Event(t_ns, "resume", f"cleared: {self.stop_reason}"))
            self.stop_category = self.stop_reason = None
            self._settle_tool()
        if self.stop_category is not None:
            if not self.power:
                return tracker.hold(), events
            setpoint = tracker.stop(reference if finite else None)
            if self.stop_category == 1 and tracker.stopped:
                self.power = False
                events.append(Event(t_ns, "power_removed", f"category 1 stop complete: {self.stop_reason}",
                                    category=1))
            return setpoint, events
        self._update_scale(safety, uncertainty, tool_speed_ahead, t_ns, events)
        before = tracker.mode.copy()
        setpoint = tracker.follow(reference)
        if tracker.failed is not None:  # ruckig refused its input: this tick braked every joint
            events.append(Event(t_ns, "tracker_failed", f"ruckig: {tracker.failed}; braking this tick"))
            tracker.failed = None
        if tracker.mode.any():
            self._report_tracking(t_ns, reference, setpoint, before, events)
        if self._tool is not None:
            self._check_tool(t_ns, setpoint, events)
        return setpoint, events

    def reset(self, q: np.ndarray) -> None:
        """Operator reset after a stop: power back on, standstill at ``q`` (measured)."""
        self.tracker.reset(q)
        self.stop_category = self.stop_reason = None
        self.power = True
        self._active.clear()
        self._effort_ticks[:] = 0
        self.scale, self._scale_rate = 1.0, 0.0
        self._settle_tool()

    def _settle_tool(self) -> None:
        """Tool point of the setpoint at standstill: the tool-speed estimate restarts from rest."""
        if self._tool is not None:
            self._tip = tuple(self._tool(self.tracker.p).tolist())

    # -- stops -----------------------------------------------------------------------------
    def _stop_request(self, t_ns, reference, finite, state, safety, last_chunk_ns, uncertainty, events):
        """(category, kind, reason) of a stop this tick asks for, or None; latches lasting causes."""
        c = self.config
        if safety.stop is not None:
            return safety.stop, "protective_stop", "safety controller protective stop input"
        if not finite:
            return 2, "reference_invalid", "non-finite reference"
        if state is not None:
            over = np.abs(state.effort) > self._effort_max
            self._effort_ticks = np.where(over, self._effort_ticks + 1, 0)
            if (self._effort_ticks >= self._effort_hold).any() and self.stop_reason != "effort limit":
                j = int(np.argmax(self._effort_ticks))
                events.append(Event(t_ns, "effort_limit", f"effort above {c.effort_fraction:.0%} of the limit "
                                    f"for {c.effort_hold_s * 1e3:.0f} ms", joint=self.profile.joint_names[j],
                                    asked=float(state.effort[j]), sent=float(self.profile.array("effort")[j])))
                self._effort_ticks[:] = 0
                return 2, "effort_stop", "effort limit"
        if last_chunk_ns is not None and t_ns - last_chunk_ns > c.watchdog_s * 1e9:
            return c.watchdog_category, "watchdog_stop", f"no fresh chunk for {c.watchdog_s * 1e3:.0f} ms"
        if (c.uncertainty_threshold is not None and c.uncertainty_action == "hold"
                and uncertainty > c.uncertainty_threshold):
            return 2, "uncertainty_hold", f"policy uncertainty {uncertainty:.3g} above {c.uncertainty_threshold:.3g}"
        if self.stop_reason == "workspace box" and finite and self._outside(self._tool(reference)):
            return 2, "workspace_stop", "workspace box"  # held while the reference points outside
        return None

    def _begin_stop(self, t_ns: int, category: int, kind: str, reason: str, events: list[Event]) -> None:
        if self.stop_category is not None and self.stop_category <= category:
            return  # a stop at least as strict is already in force
        self.stop_category, self.stop_reason = category, reason
        events.append(Event(t_ns, kind, reason, category=category))
        if category == 0 and self.power:
            self.power = False
            events.append(Event(t_ns, "power_removed", f"category 0 stop: {reason}", category=0))

    # -- speed -----------------------------------------------------------------------------
    def _update_scale(self, safety, uncertainty, speed_ahead, t_ns, events) -> None:
        c = self.config
        reduced = safety.reduced_speed
        self._condition(t_ns, "reduced_speed_input", reduced, "safety controller reduced-speed input", events)
        gate = (c.uncertainty_threshold is not None and c.uncertainty_action == "reduce"
                and uncertainty > c.uncertainty_threshold)
        self._condition(t_ns, "uncertainty_gate", gate,
                        f"policy uncertainty {uncertainty:.3g} above {c.uncertainty_threshold}", events)
        cap = c.reduced_speed if (reduced or gate) else c.tool_speed_max
        target = 1.0
        if cap is not None:
            if speed_ahead is None:
                target = REDUCED_SCALE_WITHOUT_TOOL if (reduced or gate) else 1.0
            elif speed_ahead > 0.0:
                target = min(1.0, 0.9 * cap / speed_ahead)
        self._ramp(target)

    def _ramp(self, target: float) -> None:
        """Move ``scale`` toward ``target`` with bounded rate and rate of rate (a 2nd-order slew)."""
        c, dt = self.config, self.dt_ns * 1e-9
        err = target - self.scale
        if err == 0.0 and self._scale_rate == 0.0:
            return
        # the rate that still stops on target with the acceleration bound
        wanted = np.sign(err) * min(c.scale_rate, np.sqrt(2.0 * c.scale_accel * abs(err)))
        step = c.scale_accel * dt
        self._scale_rate += float(np.clip(wanted - self._scale_rate, -step, step))
        self.scale = float(np.clip(self.scale + self._scale_rate * dt, 0.0, 1.0))
        if abs(target - self.scale) < 1e-6 and abs(self._scale_rate) < step:
            self.scale, self._scale_rate = target, 0.0

    # -- reporting ---------------------------------------------------------------------------
    def _condition(self, t_ns: int, kind: str, on: bool, reason: str, events: list[Event]) -> None:
        if on and kind not in self._active:
            self._active.add(kind)
            events.append(Event(t_ns, kind, reason))
        elif not on and kind in self._active:
            self._active.discard(kind)
            events.append(Event(t_ns, f"{kind}_cleared", reason))

    def _report_tracking(self, t_ns, reference, setpoint, before, events) -> None:
        """One event per joint when the tracker takes it over after a stretch of pass-through."""
        names = self.profile.joint_names
        quiet = t_ns - self._last_intervention >= INTERVENTION_QUIET_NS
        self._last_intervention[self.tracker.mode != PASS] = t_ns
        for j in np.flatnonzero(quiet & (before == PASS) & (self.tracker.mode != PASS) & (self.tracker.mode != STOP)):
            events.append(Event(t_ns, "limit_intervention", "reference outside the velocity, acceleration, jerk "
                                "or position envelope; ruckig takes over", joint=names[j],
                                asked=float(reference[j]), sent=float(setpoint[j])))
        for j in np.flatnonzero((before != STOP) & (self.tracker.mode == STOP)):
            events.append(Event(t_ns, "limit_brake", "braking: a stop no longer fits before the soft limit",
                                joint=names[j], asked=float(reference[j]), sent=float(setpoint[j])))

    def _check_tool(self, t_ns: int, setpoint: np.ndarray, events: list[Event]) -> None:
        x, y, z = self._tool(setpoint).tolist()
        px, py, pz = self._tip
        inv_dt = 1e9 / self.dt_ns
        vx, vy, vz = (x - px) * inv_dt, (y - py) * inv_dt, (z - pz) * inv_dt
        self._tip = (x, y, z)
        self.tool_speed = math.sqrt(vx * vx + vy * vy + vz * vz)
        if self._box is not None:
            # where a stop from here could end: the tool coasts at most v * T / 2 + v * (jerk ramp) while the
            # slowest joint brakes for T = |v| / a_max
            t_stop = max(abs(v) * ia for v, ia in zip(self.tracker.v.tolist(), self._inv_a))
            k = 0.5 * t_stop + self._t_jerk
            if self._outside((x + vx * k, y + vy * k, z + vz * k)):
                self._begin_stop(t_ns, 2, "workspace_stop", "workspace box", events)

    def _outside(self, point) -> bool:
        lo, hi = self._box
        return any(p < low or p > high for p, low, high in zip(point, lo, hi))
