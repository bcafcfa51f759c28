"""Workspace box for the tool point [m]: a category 2 stop that ends inside the box, from look-ahead.

After tracking, the stop the tracker would run from the setpoint just computed is checked; if the
tool point could leave the box on its way, that setpoint is not sent and the stop starts from the
last one instead, which was checked the same way a tick before. The stop brakes each joint on its
own, so the tool does not coast along a line: the stop is planned whole (``Tracker.stop_plan``)
and the tool point checked at samples along it, each inside the box by a margin that bounds the
path between samples by the joints' travel and their reach (``reach.max_reach``); a span of
samples whose ends clear the walls by half its whole travel needs none of the tool points between
(forward kinematics was most of a sampled tick), nor the samples themselves where every joint's stop
moves it one way only (its travel between two samples is then the difference of its positions there;
evaluating all ten samples and their gaps was most of what was left). Cheap bounds of every joint's
stopping distance skip all that while the tool is far from the walls.

Outside the box (a reset at a pose outside it, a stop that ended outside), motion that brings the
tool back is allowed and motion further out is not: on the first tick of motion the box is grown
wall by wall to hold the tool point with ``SLACK`` to spare (``grown_box``: a wall the tool is inside
of stays a wall), and it shrinks back as the tool point comes in; there only where a stop would end
is checked. The approach and the start-up's first target (``runtime``) keep to the same grown box.
Before tracking, a workspace stop is held until the way on leads the tool back in (``WorkspaceHold``), so one
excursion is at most one stop.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from cellguard.control.checks.check import Check, Stop, Tick
from cellguard.control.config import Box
from cellguard.control.events import EventKind
from cellguard.control.reach import max_reach
from cellguard.control.tracker import StopPlan, Tracker
from cellguard.embodiment import Profile

STOP = Stop(2, EventKind.WORKSPACE_STOP, "workspace box")
SLACK = 0.002  # [m] the grown box holds a tool point found outside by this much
SAMPLES = 10  # most samples along a stop's path, closer together in time at its start where the joints are fastest
SPACING = 0.005  # [m] about this much of the travel bound between two samples
MIN_SAMPLES = 4  # the first segment short enough that the tool point itself needs no margin to speak of
# each sample's time as a fraction of the stop's, for each number of samples: even steps of a braking joint
_FRACTIONS = {n: [0.0] + [1.0 - math.sqrt(1.0 - k / n) for k in range(1, n)] + [1.0] for n in range(1, SAMPLES + 1)}
RESUME_INSIDE = 0.01  # [m] a workspace stop holds until the reference's tool point is this far inside the box
PROBE_STEP = 1e-3  # [rad or m] the step toward the reference that shows where the recovery leads the tool


def grown_box(point, lo, hi, grown=None) -> tuple[tuple, tuple] | None:
    """The box ``lo``..``hi`` [m] grown wall by wall to hold ``point`` [m], a tool point found outside it: a wall the
    point is past moves out to it plus ``SLACK``, a wall it is inside of stays (every wall pushed out by how far the
    point was out let a tool over the ceiling swing past a side wall). None where the point is inside every wall.
    ``grown``: the box grown so before, shrunk to hold ``point`` as it comes in: a wall moved out moves back to
    ``SLACK`` past it, or past the wall itself where the point is inside it (the caller drops the grown box)."""
    if grown is not None:
        return (tuple(g if g == a else max(g, min(p, a) - SLACK) for p, a, g in zip(point, lo, grown[0])),
                tuple(g if g == b else min(g, max(p, b) + SLACK) for p, b, g in zip(point, hi, grown[1])))
    out_lo = tuple(float(p) - SLACK if p < a else float(a) for p, a in zip(point, lo))
    out_hi = tuple(float(p) + SLACK if p > b else float(b) for p, b in zip(point, hi))
    return None if out_lo == tuple(map(float, lo)) and out_hi == tuple(map(float, hi)) else (out_lo, out_hi)


def box_excess(point, lo, hi) -> tuple[float, str]:
    """How far ``point`` [m] lies outside the box ``lo``..``hi`` on its worst axis [m] (below 0 inside: minus the
    distance to the nearest wall), and that wall ("z max")."""
    excess, axis, side = max(((max(a - p, p - b), k, "min" if a - p > p - b else "max")
                              for k, (p, a, b) in enumerate(zip(point, lo, hi))), key=lambda e: e[0])
    return float(excess), f"{'xyz'[axis]} {side}"


def mm(distance: float) -> str:
    """A distance [m] in mm: one decimal under 1 mm (a tool a fraction of a mm out read "0 mm outside")."""
    return f"{distance * 1e3:.1f}" if abs(distance) < 1e-3 else f"{distance * 1e3:.0f}"


def at(point, lo, hi) -> list[float]:
    """``point`` [m] to the mm, each coordinate with as many more digits as show which side of its walls it lies."""
    shown = []
    for p, a, b in zip(map(float, point), lo, hi):
        digits = 3
        while digits < 9 and ((p < a) != (round(p, digits) < a) or (p > b) != (round(p, digits) > b)):
            digits += 1
        shown.append(round(p, digits) + 0.0)  # no -0.0
    return shown


def _depth(point, lo, hi) -> float:
    """How far ``point`` lies inside the box from its nearest wall [m] (below 0 outside)."""
    return min(min(p - a, b - p) for p, a, b in zip(point, lo, hi))


def _inside(point, lo, hi, margin: float) -> bool:
    """Is the ball of radius ``margin`` about ``point`` inside the box? (Axis by axis, unrolled: a few times cheaper
    than a generator over them, and the look-ahead asks it several times a tick near a wall.)"""
    (x, y, z), (x0, y0, z0), (x1, y1, z1) = point, lo, hi
    return x0 + margin <= x <= x1 - margin and y0 + margin <= y <= y1 - margin and z0 + margin <= z <= z1 - margin


class WorkspaceLookahead(Check):
    """After tracking: refuse the setpoint if a stop from it could take the tool point out of ``box``."""

    def __init__(self, box: Box, profile: Profile, tool: Callable[[np.ndarray], np.ndarray], tracker: Tracker):
        self._lo, self._hi = tuple(map(float, box[0])), tuple(map(float, box[1]))
        self._tool, self._tracker = tool, tracker
        reach = max_reach(tool, profile.q_min, profile.q_max)
        self._reach = reach.norm
        self._moving = tuple(j for j, k in enumerate(reach.norm) if k > 1e-6)  # the joints that move the tool point
        self._axis_reach = [tuple(axis[j] for axis in reach.axes) for j in self._moving]  # (x, y, z) per joint
        self._grown: tuple[tuple, tuple] | None = None  # the box grown to hold a tool point found outside it
        self._still = True  # the tracker starts this tick from standstill (construction, reset, resume)

    def request(self, tick: Tick) -> Stop | None:
        tip, tracker = tick.tip, self._tracker
        # from standstill (built, reset) or a stop that left the tool outside a box not grown yet: taken as it is; a
        # grown box only shrinks, a stop's too (rebuilt at every stop, a tool held by watchdog stops between its
        # chunks crept 36 mm further out in 20 s with no workspace stop)
        if self._still or (tick.stop_kind is not None and self._grown is None):
            self._grown, self._still = grown_box(tip, self._lo, self._hi), False
        elif self._grown:
            self._grown = grown_box(tip, self._lo, self._hi, self._grown)
        if self._path_fits(tip, tracker):
            self._grown = None
            return None
        return None if self._grown and self._end_fits(tracker) else STOP

    def reset(self) -> None:
        self._still = True

    def _path_fits(self, tip, tracker: Tracker) -> bool:
        """Does a stop from the setpoint keep the tool point inside the box all the way? Two bounds from the
        joints' travel first (a loose one, a few multiplications; then the stop profile's), then the planned
        stop itself."""
        moving, axis_reach = self._moving, self._axis_reach
        if self._far_from_walls(tip, tracker.stop_travel_bound(moving, axis_reach)) or self._far_from_walls(
                tip, tracker.stop_travel(moving, axis_reach)):
            return True
        lo, hi, reach = self._lo, self._hi, self._reach
        plan = tracker.stop_plan()
        if plan is None:  # ruckig refuses the state: the stop holds the setpoint where it is
            return _inside(tip, lo, hi, 0.0)
        path = _StopPath(plan, tracker.samples[0], tip, reach, self._tool)
        return self._span_fits(0, path.n, path)

    def _span_fits(self, i: int, j: int, path: _StopPath) -> bool:
        """Does the tool path between samples ``i`` and ``j`` stay inside the box? Yes where both ends lie inside
        by half the travel between them (a path between two samples stays within half of it of one of them);
        else each half is asked, down to single gaps. Most stops keep well inside, and their end alone shows
        it: the tool point at every sample is needed only near a wall."""
        a, b = path.point(i), path.point(j)
        margin = path.margin(i, j)
        lo, hi = self._lo, self._hi
        if _inside(a, lo, hi, margin) and _inside(b, lo, hi, margin):
            return True
        if j - i == 1:
            return False
        m = (i + j) // 2
        return self._span_fits(i, m, path) and self._span_fits(m, j, path)

    def _far_from_walls(self, tip, reach: tuple[float, float, float]) -> bool:
        """Does the tool point stay inside the box, axis by axis, while it moves up to ``reach`` along each?"""
        (x, y, z), (x0, y0, z0), (x1, y1, z1), (rx, ry, rz) = tip, self._lo, self._hi, reach
        return x0 + rx <= x <= x1 - rx and y0 + ry <= y <= y1 - ry and z0 + rz <= z <= z1 - rz

    def _end_fits(self, tracker: Tracker) -> bool:
        """Outside the box: does a stop from the setpoint end inside the grown box (past no wall further than the
        tool point was, ``SLACK`` allowed for the path between)?"""
        plan = tracker.stop_plan()
        end = tracker.samples[0] if plan is None else plan.at(plan.duration)
        return _inside(self._tool(np.asarray(end)).tolist(), *self._grown, 0.0)


class WorkspaceHold(Check):
    """Before tracking: keep a workspace stop until the reference's tool point lies ``RESUME_INSIDE`` inside
    ``box`` and, where the tool point is nearer a wall than that, the way to it leads the tool deeper in.

    A reference that runs along a wall would take the tool back to it at once, and a tool point at a wall
    that the recovery (a straight line in joint space from standstill) leads along or out of it would
    stop again at once: a stop a resume, hundreds a second.
    """

    def __init__(self, box: Box, tool: Callable[[np.ndarray], np.ndarray], tracker: Tracker):
        self._lo, self._hi = tuple(map(float, box[0])), tuple(map(float, box[1]))
        self._tool, self._tracker = tool, tracker

    def request(self, tick: Tick) -> Stop | None:
        if tick.stop_kind != EventKind.WORKSPACE_STOP or not tick.finite:
            return None
        lo, hi, tool = self._lo, self._hi, self._tool
        if not _inside(tool(tick.reference).tolist(), lo, hi, RESUME_INSIDE):
            return STOP
        q = self._tracker.p
        depth = _depth(tool(q).tolist(), lo, hi)
        if depth >= RESUME_INSIDE:
            return None
        way = tick.reference - q
        step = q + way * min(1.0, PROBE_STEP / float(np.abs(way).max()))
        return None if _depth(tool(step).tolist(), lo, hi) > depth else STOP


class _StopPath:
    """A planned stop's samples, even steps of a braking joint in time (closer together at its start, where the
    joints are fastest), each evaluated (its positions, then its tool point) only where a span asks for it.

    The travel between two samples, a bound of the tool's path between them, is the sum over the joints of
    reach times the joint's travel: for a joint that moves one way only, the difference of its positions at the
    two (its samples in between add up to no more); for one whose stop turns back (``StopPlan.turning``), the
    sum of its steps between every sample of the span, all evaluated at once.
    """

    def __init__(self, plan: StopPlan, q0: list[float], tip, reach: list[float], tool: Callable):
        self._at, self._tool = plan.at, tool
        duration, end = plan.duration, plan.at(plan.duration)
        travel = sum(k * abs(e - q) for k, e, q in zip(reach, end, q0))  # a bound of the tool's, along a line
        self.n = n = min(SAMPLES, max(MIN_SAMPLES, math.ceil(travel / SPACING)))
        self._times = [duration * f for f in _FRACTIONS[n]]
        self._qs = [q0] + [None] * (n - 1) + [end]
        self._points = [tip] + [None] * n
        turning = [j for j in plan.turning if reach[j]]
        self._weight, self._turned = reach, [0.0] * (n + 1)  # per joint; the turning joints' travel up to a sample
        if turning:
            qs = self._qs
            for k in range(1, n):
                qs[k] = plan.at(self._times[k])
            self._weight = [0.0 if j in turning else k for j, k in enumerate(reach)]
            turned = self._turned
            for k in range(n):
                turned[k + 1] = turned[k] + sum(reach[j] * abs(qs[k + 1][j] - qs[k][j]) for j in turning)

    def _q(self, k: int) -> list[float]:
        """The joint positions at sample ``k``."""
        q = self._qs[k]
        if q is None:
            q = self._qs[k] = self._at(self._times[k])
        return q

    def point(self, k: int) -> list[float]:
        """The tool point at sample ``k``."""
        point = self._points[k]
        if point is None:
            point = self._points[k] = self._tool(np.asarray(self._q(k))).tolist()
        return point

    def margin(self, i: int, j: int) -> float:
        """Half the travel between samples ``i`` and ``j`` [m]."""
        a, b = self._q(i), self._q(j)
        return 0.5 * (sum(w * abs(y - x) for w, x, y in zip(self._weight, a, b)) + self._turned[j] - self._turned[i])
