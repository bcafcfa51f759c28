"""Executor: action chunks in, a time-indexed joint reference out, at every servo tick.

A chunk is checked and fitted once, when it is received (``prepare``, off the servo path: on
hardware, the thread that receives inference results); ``push`` at a servo tick only swaps
it in, and ``reference`` evaluates a cubic per tick.

Stitching: a crossfade. When a chunk arrives, the reference being played fades out and the new
chunk's curve fades in over ``blend`` (default 200 ms), weighted by the quintic smoothstep, whose
rate and rate of rate are zero at both ends: the reference is continuous in position, velocity and
acceleration at the switch and at the end of the blend, and each chunk is itself a C2 cubic (see
``spline``). Between the two, the reference is a weighted mean of the chunks' curves, so it stays
within what the chunks asked for. A reference at rest (before the first chunk, or once a curve has
ended) fades out as the new curve less its own state at the switch, joint by joint where that keeps
nearer the rest (``_hold_for``): a hold that stayed put made the reference catch up with a plan from
rest at twice its acceleration. An offset that carried the old reference's velocity and
acceleration minus the new chunk's (a quintic decay, one polynomial per tick) cost less, but those
differences come from each chunk's spline through its knots: 1 mrad of noise between a learned
policy's steps turned into 22 mrad rms of reference error (65 mrad at most), and a 3 mrad zig-zag
overshot by 45 mrad, compounding at every switch. Chunks faster than the blend overlap (at
20 Hz, five curves): each curve's weight is one float, and one dot product evaluates them all.
The blend is long because consecutive chunks from the same plan differ by their interpolation
error near the plan's jerk steps, and a short blend turns that into jerk. Prefix-conditioned
chunking (real-time chunking) would avoid the blend, but it needs a policy that takes the executed
prefix as an input, which most cannot; the blend works for every source, and what it cannot make
smooth (chunks that disagree by more than the limits allow within the blend) the tracker brings
back within the limits.

Time: chunks are stamped in the policy's (real) time; the reference is read on a playback
clock that runs at ``scale`` (1 = real time). Speed scaling slows the clock, so the path keeps
its geometry and only time stretches. A chunk's steps are placed on the playback clock from the
time of the observation they answer (a chunk stamped more than a servo period after the tick it
arrives on answers no observation yet made: refused); steps already behind the clock when the chunk arrives are
dropped (the curve is never read before now), never replayed; except the first chunk's: the robot waited at rest
(the start, or an approach) while the policy thought, so it starts when it is taken, as if observed then (cut, its
first steps' motion was made up in the blend from rest, 0.63 rad in 200 ms for a 1 s chunk 450 ms late, and the
tracker lagged the plan by as much). After a chunk ran out the setpoint may still be braking: a late chunk's steps
are dropped there as anywhere (replayed, a plan of the robot's own path was missed by 0.22 rad). With ``max_tick_ns`` (the guard
sets one servo period) the playback clock advances at most that much per tick: a tick that
wakes late on wall time does not jump the reference (a 1 ms finite difference reads a 2 ms
step as a velocity spike); the time lost becomes lag, as a slow-down would, and later chunks
are placed on the lagging clock.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cellguard.control.events import Event, EventKind
from cellguard.control.spline import ChunkCurve
from cellguard.embodiment import Profile
from cellguard.policy.chunk import MAX_HORIZON, ActionChunk

MIN_STEP_NS, MAX_STEP_NS = 1_000_000, 1_000_000_000  # a chunk's step: 1 ms to 1 s
MAX_STAMP_NS = 2**62  # a chunk's stamp, either sign: 146 years, and the curve's int64 clock arithmetic still fits
HISTORY_TICKS = 8192  # playback clock remembered for mapping late chunks [ticks]
MAX_BLENDED = 64  # curves in one blend at most, a bound on the tick's cost (50 Hz chunks in a 1 s blend: 51)
_FOREVER = 2**63  # later than any playback time [ns]
_RESTACK = (-_FOREVER, (), None)  # a blend stack to build anew
HOLD_SAMPLES = 65  # samples of a blend that decide, per joint, how a hold fades out when a chunk comes from rest


@dataclass(frozen=True)
class PreparedChunk:
    """A chunk checked and fitted, or refused (``problem`` says why). Built off the servo path."""

    t_obs_ns: int
    dt_ns: int
    curve: ChunkCurve | None = None
    uncertainty: np.ndarray | None = None  # (H,), or None
    tool_speed: np.ndarray | None = None  # (H-1,) chord speed of the tool between steps at scale 1 [m/s]
    problem: str | None = None


def _fade(x: float) -> float:
    """Weight of the reference before a switch, ``x`` (0..1) through the blend: 1 - the quintic smoothstep, so
    the blend's value, rate and rate of rate match the old reference at 0 and the new chunk at 1; 0 past it
    (the polynomial goes negative there: a curve weighed below zero pushed the reference out of the chunks' span)."""
    if x >= 1.0:
        return 0.0
    return 1.0 - x * x * x * (10.0 + x * (6.0 * x - 15.0))


def _past(curve: ChunkCurve, first: int, now: int) -> str | None:
    """Why ``curve``, its first step at ``first``, plays nothing at playback time ``now`` (all its steps before it)."""
    horizon = len(curve.points)
    return f"all {horizon} steps lie before now" if first + (horizon - 1) * curve.h_ns <= now else None


class Executor:
    """Holds the chunk being played and answers ``reference(t_ns)``; refuses bad chunks with events.

    ``tool`` maps joint positions (D,) to the tool point (3,) [m]; with it, each chunk carries
    its tool speeds so the envelope can slow down before a fast stretch, not during it.
    """

    def __init__(self, profile: Profile, q0: np.ndarray, dt_ns: int, blend_ns: int = 200_000_000,
                 tool: Callable[[np.ndarray], np.ndarray] | None = None, max_tick_ns: int | None = None):
        self.profile, self.dt_ns, self.blend_ns, self._tool = profile, int(dt_ns), int(blend_ns), tool
        self._max_tick_ns = max_tick_ns  # most the playback clock advances per tick [ns] (None: no bound)
        self._span = profile.q_max - profile.q_min
        self._curve = ChunkCurve(0, 1, np.array(q0, dtype=np.float64)[None])  # a hold
        self._older: list[tuple[ChunkCurve, int, int]] = []  # curves fading out: (curve, switched, blend) [ns]
        self._stack = _RESTACK  # the blend's curves at their segments: (valid until [ns], parts, coefficients)
        self._chunk: PreparedChunk | None = None
        self._t_ns: int | None = None
        self.tau_ns = 0  # playback clock
        self._history = np.zeros(HISTORY_TICKS, dtype=np.int64)  # t - tau per tick, by tick index
        self.last_chunk_ns: int | None = None
        self.uncertainty = 0.0
        self._ahead: tuple = (None, 0, 0, 0.0)  # (chunk, k0, k1, fastest tool speed there) of the last call

    # -- off the servo path ------------------------------------------------------------------
    def prepare(self, chunk: ActionChunk) -> PreparedChunk:
        """Check ``chunk`` and fit its curve; a malformed chunk comes back with ``problem`` set."""
        problem = self._check(chunk)
        if problem is not None:
            return PreparedChunk(0, 0, problem=problem)
        actions = np.array(chunk.actions, dtype=np.float64)
        actions.setflags(write=False)
        curve = ChunkCurve(chunk.t_obs_ns + chunk.dt_ns, chunk.dt_ns, actions)
        unc = None if chunk.uncertainty is None else np.array(chunk.uncertainty, dtype=np.float64)
        speed = None
        if self._tool is not None and len(actions) > 1:
            tips = np.array([self._tool(q) for q in actions])
            speed = np.linalg.norm(np.diff(tips, axis=0), axis=1) / (chunk.dt_ns * 1e-9)
        return PreparedChunk(int(chunk.t_obs_ns), int(chunk.dt_ns), curve, unc, speed)

    # -- on the servo path -------------------------------------------------------------------
    def push(self, chunk: ActionChunk | PreparedChunk, t_ns: int) -> list[Event]:
        """Take a chunk at servo tick ``t_ns``; a malformed, stale or out-of-order chunk is refused."""
        if isinstance(chunk, ActionChunk):
            chunk = self.prepare(chunk)
        if chunk.problem is not None:
            return [Event(t_ns, EventKind.CHUNK_REJECTED, chunk.problem)]
        if chunk.t_obs_ns - t_ns > self.dt_ns:  # taken, it would block every later chunk as out of order
            return [Event(t_ns, EventKind.CHUNK_REJECTED, f"stamped {(chunk.t_obs_ns - t_ns) * 1e-9:.3f} s after "
                                                          "this tick: it answers an observation not yet made (a "
                                                          "policy or robot stamping on another clock)")]
        if self._chunk is not None and chunk.t_obs_ns == self._chunk.t_obs_ns:
            return []  # the same answer again (a policy with nothing new): no new information
        if self._chunk is not None and chunk.t_obs_ns < self._chunk.t_obs_ns:
            return [Event(t_ns, EventKind.CHUNK_REJECTED, f"out of order: answers t={chunk.t_obs_ns * 1e-9:.3f} s, "
                                                  f"not newer than the chunk in use ({self._chunk.t_obs_ns * 1e-9:.3f} s)")]
        now, shift = self._when(chunk, t_ns)
        curve = chunk.curve
        first, h = curve.t0_ns - shift, curve.h_ns
        stale = _past(curve, first, now)
        if stale is not None:
            return [Event(t_ns, EventKind.CHUNK_STALE, stale)]
        horizon = len(curve.points)
        if first <= now and self._chunk is None:  # the first: the robot waited at rest while the policy thought, so
            first += now - (chunk.t_obs_ns - shift)  # its plan starts now, not cut (450 ms cut 0.63 rad off a 1 s chunk)
        placed = curve.shifted(first) if first != curve.t0_ns else curve
        old = self._curve
        events = self._ran_out(old, now, t_ns)
        if self._resting(now):  # a hold fades out as the new curve less its state at the switch
            old = self._hold_for(old.points[-1], placed, now)
        # fades out before it ends: a curve held past its end lags its plan (1 s blends of 0.5 s chunks drove the
        # tracker into its limits)
        self._older.append((old, now, self._blend_for(old, now)))
        if len(self._older) > MAX_BLENDED:  # chunks far faster than the blend: the oldest curve goes (a step of
            del self._older[0]              # its weight, the price of a bounded tick)
        self._curve, self._stack = placed, _RESTACK
        self._chunk = PreparedChunk(chunk.t_obs_ns, chunk.dt_ns, placed, chunk.uncertainty, chunk.tool_speed)
        self.last_chunk_ns = t_ns
        dropped = int(min(max((now - first) // h + 1, 0), horizon))
        if dropped:
            events.append(Event(t_ns, EventKind.CHUNK_STEPS_DROPPED, f"{dropped} steps already past"))
        return events

    def stale(self, chunk: PreparedChunk, t_ns: int) -> str | None:
        """Why a checked ``chunk`` taken at servo tick ``t_ns`` would play nothing (all its steps lie before the
        playback time then), or None. The loop asks it of a first chunk too: a stale one started the run, and the
        next chunk, far from the pose, was played with no approach."""
        now, shift = self._when(chunk, t_ns)
        return _past(chunk.curve, chunk.curve.t0_ns - shift, now)

    def _when(self, chunk: PreparedChunk, t_ns: int) -> tuple[int, int]:
        """The playback time at servo tick ``t_ns``, and how far the playback clock lagged real time when ``chunk``'s
        observation was made [ns]."""
        now = t_ns if self._t_ns is None else self.tau_ns + self._elapsed(t_ns)
        return now, self._offset_at(chunk.t_obs_ns)

    def _ran_out(self, old: ChunkCurve, now: int, t_ns: int) -> list[Event]:
        """The event for a chunk in use that ended before the one arriving at ``now`` (playback time): the reference
        held its last step meanwhile and stopped dead, and the guard's interventions braking it said nothing of why.
        Told here, once per run-out and off the tick, with how long the reference held."""
        if self._chunk is None or old.end_ns >= now:  # a hold before the first chunk, or the next came in time
            return []
        return [Event(t_ns, EventKind.CHUNK_RAN_OUT, f"the chunk in use ran out {(now - old.end_ns) * 1e-6:.0f} ms "
                                                     f"before this one arrived: its last step was held meanwhile")]

    def reference(self, t_ns: int, scale: float = 1.0) -> np.ndarray:
        """The joint reference (D,) at servo tick ``t_ns``; the playback clock advances by ``scale``."""
        if self._t_ns is None:
            self.tau_ns = t_ns
        elif scale == 1.0:
            self.tau_ns += self._elapsed(t_ns)
        else:
            self.tau_ns += round(scale * self._elapsed(t_ns))
        self._t_ns = t_ns
        self._history[(t_ns // self.dt_ns) % HISTORY_TICKS] = t_ns - self.tau_ns
        tau, chunk = self.tau_ns, self._chunk
        if chunk is not None and chunk.uncertainty is not None:
            k = (tau - chunk.curve.t0_ns) // chunk.dt_ns
            self.uncertainty = float(chunk.uncertainty[min(max(k, 0), len(chunk.uncertainty) - 1)])
        older = self._older
        if older and tau - older[-1][1] >= older[-1][2]:  # the newest switch's blend is over
            older.clear()
            self._stack = _RESTACK
        while older and tau - older[0][1] >= older[0][2]:  # the oldest curve's own switch is over: it weighs nothing
            del older[0]
            self._stack = _RESTACK
        if not older:
            return self._curve.at(tau)
        # reference = c_n + w_n (c_n-1 + w_n-1 (... - c_n-1) - c_n): each curve's weight as one float, then one
        # dot over the curves' segment coefficients, stacked anew only when a curve enters a segment
        stack = self._stack
        if tau >= stack[0]:
            stack = self._restack(tau)
        powers, keep = [], 1.0
        for start, held_u, switched, blend in stack[1]:
            if switched is None:  # the oldest curve: what the newer ones' switches left of the weight
                weight = keep
            else:  # a curve that came in at ``switched``: the old blend fades out under it
                w = _fade((tau - switched) / blend)
                weight = keep * (1.0 - w)
                keep *= w
            u = held_u if start is None else (tau - start) * 1e-9
            powers += (weight, weight * u, weight * u * u, weight * u * u * u)
        return np.dot(powers, stack[2])

    def _restack(self, tau: int) -> tuple:
        """The blend's curves, newest first, at their segments at ``tau``: each segment's start (None once the curve
        is held: its time into the segment is then fixed), the switch the curve came in at (None for the oldest),
        and their coefficients stacked; valid until the first curve leaves its segment. Built when a curve enters a
        segment, so a tick reads each curve's time into its segment with one subtraction (a ``segment`` call per
        curve cost about 1.5 µs of a five-curve blend)."""
        curves = [self._curve] + [c for c, _, _ in reversed(self._older)]
        came_in = [(switched, blend) for _, switched, blend in reversed(self._older)] + [(None, None)]
        until, parts, blocks = _FOREVER, [], []
        for curve, (switched, blend) in zip(curves, came_in):
            k, u = curve.segment(tau)
            blocks.append(curve.coefficients[k])
            if tau >= curve.end_ns:
                parts.append((None, u, switched, blend))
            else:
                start = curve.t0_ns + k * curve.h_ns
                parts.append((start, None, switched, blend))
                until = min(until, start + curve.h_ns, curve.end_ns)
        self._stack = (until, parts, np.concatenate(blocks))
        return self._stack

    def _resting(self, now: int) -> bool:
        """Is the reference at rest at playback time ``now``: its curve ended (or a hold) and no blend running?"""
        older = self._older
        return self._curve.end_ns <= now and (not older or now - older[-1][1] >= older[-1][2])

    def _hold_for(self, q: np.ndarray, curve: ChunkCurve, now: int) -> ChunkCurve:
        """What a hold at ``q`` fades out as when ``curve`` takes over at ``now``: per joint, the curve less its
        position, velocity and acceleration at ``now`` (at rest at ``q``, then moving as the curve does beyond
        that), where it keeps nearer ``q`` over the blend than the curve does; else the hold.

        A hold stays put while the curve moves on: weighted with it, the reference lagged the curve and caught up
        at up to 2.4 times its acceleration, whatever the blend's length. A plan from rest ramps its acceleration
        up under the jerk limit, so at the switch, a latency after it began, it has little (a learned arm policy's
        first chunk: 1.4 rad/s² there, 7.2 later, entered at 15.02 against the 15 limit). Less its own motion the
        curve differs from the hold by that state only. A noisy curve's velocity and acceleration at the switch
        carry it away from ``q`` (a 3 mrad zig-zag by 0.17 rad): that joint fades out of the hold as before."""
        until = now + self.blend_ns
        knots = np.arange(now, until + 1, curve.h_ns)
        if len(knots) > HOLD_SAMPLES:  # 1 ms steps over a 1 s blend: a thousand samples on the servo tick
            knots = np.linspace(now, until, HOLD_SAMPLES).astype(np.int64)
        at, (q_at, v, half_a) = curve.at_times(knots), curve.state_at(now)
        d = ((knots - now) * 1e-9)[:, None]
        away = np.abs(at - q_at - d * (v + d * half_a)).max(axis=0)  # the curve less its motion, from q
        near = away <= np.abs(at - q).max(axis=0)
        if not near.any():
            return ChunkCurve(now, 1, q[None])
        moving = curve.less_motion(now, q, until)
        held = np.zeros_like(moving.coefficients)
        held[:, 0] = q
        moving.points = np.where(near, moving.points, q)
        moving.coefficients = np.where(near, moving.coefficients, held)
        return moving

    def _blend_for(self, old: ChunkCurve, now: int) -> int:
        """How long ``old`` fades out from ``now`` [ns]: ``blend_ns``, or less where it ends sooner (a curve that
        has ended holds its last point and fades over the whole blend); one servo period at least."""
        left = old.end_ns - now
        return self.blend_ns if left <= 0 else max(min(self.blend_ns, left), self.dt_ns)

    def _elapsed(self, t_ns: int) -> int:
        """Time since the last tick, at most ``max_tick_ns`` [ns]."""
        elapsed = t_ns - self._t_ns
        limit = self._max_tick_ns
        return elapsed if limit is None or elapsed <= limit else limit

    def tool_speed_ahead(self, window_ns: int) -> float | None:
        """Fastest tool chord speed of the chunk in use over the next ``window_ns`` of playback [m/s]."""
        chunk = self._chunk
        if chunk is None or chunk.tool_speed is None:
            return None
        c = chunk.curve
        k0 = min(max((self.tau_ns - c.t0_ns) // c.h_ns, 0), len(chunk.tool_speed) - 1)
        k1 = min(max((self.tau_ns + window_ns - c.t0_ns) // c.h_ns + 1, k0 + 1), len(chunk.tool_speed))
        ahead = self._ahead  # the window moves once per chunk step, not every tick: keep its maximum
        if ahead[0] is not chunk or ahead[1] != k0 or ahead[2] != k1:
            ahead = self._ahead = (chunk, k0, k1, float(chunk.tool_speed[k0:k1].max()))
        return ahead[3]

    def _offset_at(self, t_obs_ns: int) -> int:
        """How far the playback clock was behind real time at ``t_obs_ns`` (0 if it never lagged)."""
        if self._t_ns is None:
            return 0
        lag_now = self._t_ns - self.tau_ns
        if t_obs_ns >= self._t_ns or lag_now == 0:
            return int(lag_now)
        if (self._t_ns - t_obs_ns) // self.dt_ns >= HISTORY_TICKS or t_obs_ns < 0:
            return int(lag_now)
        return int(self._history[(t_obs_ns // self.dt_ns) % HISTORY_TICKS])

    def _check(self, chunk: ActionChunk) -> str | None:
        dof = self.profile.dof
        actions = chunk.actions
        if not isinstance(actions, np.ndarray) or actions.ndim != 2:
            return f"actions must be a 2-D array (H, {dof}), got shape {np.shape(actions)}"
        if not 0 < actions.shape[0] <= MAX_HORIZON or actions.shape[1] != dof:
            return f"actions shape {actions.shape} does not match (1..{MAX_HORIZON}, {dof})"
        if not np.issubdtype(actions.dtype, np.number) or np.issubdtype(actions.dtype, np.complexfloating):
            return f"actions dtype {actions.dtype} is not real"
        if not np.isfinite(actions).all():
            bad = np.argwhere(~np.isfinite(actions))[0]
            return f"non-finite action at step {bad[0]}, joint {self.profile.joint_names[bad[1]]}"
        far = (actions < self.profile.q_min - self._span) | (actions > self.profile.q_max + self._span)
        if far.any():
            step, j = np.argwhere(far)[0]
            return (f"action {actions[step, j]:.3g} at step {step}, joint {self.profile.joint_names[j]}, "
                    f"lies a whole range beyond the limits [{self.profile.q_min[j]:g}, {self.profile.q_max[j]:g}]")
        if not isinstance(chunk.dt_ns, (int, np.integer)) or not MIN_STEP_NS <= chunk.dt_ns <= MAX_STEP_NS:
            return f"dt_ns must be an integer in [{MIN_STEP_NS}, {MAX_STEP_NS}] ns, got {chunk.dt_ns!r}"
        stamp = chunk.t_obs_ns
        if (not isinstance(stamp, (int, np.integer)) or isinstance(stamp, bool)  # True read as 1 ns
                or not -MAX_STAMP_NS <= int(stamp) <= MAX_STAMP_NS):
            return f"t_obs_ns must be an integer in [-2**62, 2**62] ns, got {chunk.t_obs_ns!r}"
        unc = chunk.uncertainty
        if unc is not None:
            unc = np.asarray(unc)
            if (unc.shape != (actions.shape[0],) or not np.issubdtype(unc.dtype, np.number)
                    or np.issubdtype(unc.dtype, np.complexfloating)):
                return f"uncertainty must be ({actions.shape[0]},) numbers, got shape {unc.shape}, dtype {unc.dtype}"
            bad = ~np.isfinite(unc) | (unc < 0)
            if bad.any():
                step = int(np.argmax(bad))
                return f"uncertainty must be finite and >= 0, got {float(unc[step]):g} at step {step}"
        return None
