"""Workspace box for the tool point [m]: a category 2 stop that ends inside the box, from look-ahead.

After tracking, the stop the tracker would run from the setpoint just computed is checked; if the
tool point could leave the box on its way, that setpoint is not sent and the stop starts from the
last one instead, which was checked the same way a tick before. The stop brakes each joint on its
own, so the tool does not coast along a line: the stop is planned whole (``Tracker.stop_plan``)
and the tool point checked at samples along it, each inside the box by a margin that bounds the
path between samples by the joints' travel and their reach (``reach.max_reach``); a span of
samples whose ends clear the walls by half its whole travel needs none of the tool points between
(forward kinematics was most of a sampled tick). Cheap bounds of every joint's stopping distance
skip all that while the tool is far from the walls.

Outside the box (a reset at a pose outside it, a stop that ended outside), motion that brings the
tool back is allowed and motion further out is not: on the first tick of motion the box is grown
to hold the tool point with ``SLACK`` to spare, and it shrinks back as the tool point comes in;
there only where a stop would end is checked. Before tracking, a workspace stop is held until the
way on leads the tool back in (``WorkspaceHold``), so one excursion is at most one stop.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from operator import mul, sub

import numpy as np

from cellguard.control.checks.check import Check, Stop, Tick
from cellguard.control.config import Box
from cellguard.control.events import EventKind
from cellguard.control.reach import max_reach
from cellguard.control.tracker import Tracker
from cellguard.embodiment import Profile

STOP = Stop(2, EventKind.WORKSPACE_STOP, "workspace box")
SLACK = 0.002  # [m] the grown box holds a tool point found outside by this much
SAMPLES = 10  # most samples along a stop's path, closer together in time at its start where the joints are fastest
SPACING = 0.005  # [m] about this much of the travel bound between two samples
MIN_SAMPLES = 4  # the first segment short enough that the tool point itself needs no margin to speak of
RESUME_INSIDE = 0.01  # [m] a workspace stop holds until the reference's tool point is this far inside the box
PROBE_STEP = 1e-3  # [rad or m] the step toward the reference that shows where the recovery leads the tool


def _excess(point, lo, hi) -> float:
    """How far ``point`` lies outside the box [m] (0 inside)."""
    return math.sqrt(sum(max(a - p, p - b, 0.0) ** 2 for p, a, b in zip(point, lo, hi)))


def _depth(point, lo, hi) -> float:
    """How far ``point`` lies inside the box from its nearest wall [m] (below 0 outside)."""
    return min(min(p - a, b - p) for p, a, b in zip(point, lo, hi))


def _inside(point, lo, hi, margin: float) -> bool:
    """Is the ball of radius ``margin`` about ``point`` inside the box?"""
    return all(a + margin <= p <= b - margin for p, a, b in zip(point, lo, hi))


class WorkspaceLookahead(Check):
    """After tracking: refuse the setpoint if a stop from it could take the tool point out of ``box``."""

    def __init__(self, box: Box, profile: Profile, tool: Callable[[np.ndarray], np.ndarray], tracker: Tracker):
        self._lo, self._hi = tuple(map(float, box[0])), tuple(map(float, box[1]))
        self._tool, self._tracker = tool, tracker
        reach = max_reach(tool, profile.q_min, profile.q_max)
        self._reach = reach.norm
        self._moving = tuple(j for j, k in enumerate(reach.norm) if k > 1e-6)  # the joints that move the tool point
        self._axis_reach = [tuple(axis[j] for axis in reach.axes) for j in self._moving]  # (x, y, z) per joint
        self._grown = 0.0  # [m] how far the box is grown to hold a tool point found outside it
        self._still = True  # the tracker starts this tick from standstill (construction, reset, resume)

    def request(self, tick: Tick) -> Stop | None:
        tip, tracker = tick.tip, self._tracker
        if self._still or tick.stop_kind is not None:  # moving from standstill: a tool point outside is taken as is
            out = _excess(tip, self._lo, self._hi)
            self._grown, self._still = (out + SLACK if out else 0.0), False
        elif self._grown:
            self._grown = min(self._grown, _excess(tip, self._lo, self._hi) + SLACK)
        if self._path_fits(tip, tracker):
            self._grown = 0.0
            return None
        return None if self._grown and self._end_fits(tracker) else STOP

    def reset(self) -> None:
        self._still = True

    def _path_fits(self, tip, tracker: Tracker) -> bool:
        """Does a stop from the setpoint keep the tool point inside the box all the way? Two bounds from the
        joints' travel first (a loose one, a few multiplications; then the stop profile's), then the planned
        stop itself."""
        moving = self._moving
        if self._far_from_walls(tip, tracker.stop_travel_bound(moving)) or self._far_from_walls(
                tip, tracker.stop_travel(moving)):
            return True
        lo, hi, reach = self._lo, self._hi, self._reach
        plan = tracker.stop_plan()
        if plan is None:  # ruckig refuses the state: the stop holds the setpoint where it is
            return _inside(tip, lo, hi, 0.0)
        duration, at = plan
        q0 = tracker.samples[0]
        end = at(duration)
        travel = sum(k * abs(e - q) for k, e, q in zip(reach, end, q0))  # a bound of the tool's, along a line
        n = min(SAMPLES, max(MIN_SAMPLES, math.ceil(travel / SPACING)))
        qs = [q0] + [at(duration * (1.0 - math.sqrt(1.0 - k / n))) for k in range(1, n)] + [end]  # even steps
        # of a braking joint; between two, the tool path stays within half the joints' travel between them,
        # times their reach, of one of the two
        gaps = [sum(map(mul, reach, map(abs, map(sub, b, a)))) for a, b in zip(qs, qs[1:])]
        points = [tip] + [None] * n  # the tool point at a sample, found only where a span needs it
        return self._span_fits(0, n, qs, gaps, points)

    def _span_fits(self, i: int, j: int, qs: list, gaps: list[float], points: list) -> bool:
        """Does the tool path between samples ``i`` and ``j`` stay inside the box? Yes where both ends lie inside
        by half the travel between them (the sum of the gaps: a path between two samples stays within half of
        it of one of them); else each half is asked, down to single gaps. Most stops keep well inside, and their
        end alone shows it: the tool point at every sample is needed only near a wall."""
        margin = 0.5 * sum(gaps[i:j])
        for k in (i, j):
            if points[k] is None:
                points[k] = self._tool(np.asarray(qs[k])).tolist()
        lo, hi = self._lo, self._hi
        if _inside(points[i], lo, hi, margin) and _inside(points[j], lo, hi, margin):
            return True
        if j - i == 1:
            return False
        m = (i + j) // 2
        return self._span_fits(i, m, qs, gaps, points) and self._span_fits(m, j, qs, gaps, points)

    def _far_from_walls(self, tip, travel: list[float]) -> bool:
        """Does the tool point stay inside the box, axis by axis, while each joint that moves it travels
        ``travel``?"""
        rx = ry = rz = 0.0
        for d, (kx, ky, kz) in zip(travel, self._axis_reach):
            rx, ry, rz = rx + kx * d, ry + ky * d, rz + kz * d
        (x, y, z), (x0, y0, z0), (x1, y1, z1) = tip, self._lo, self._hi
        return x0 + rx <= x <= x1 - rx and y0 + ry <= y <= y1 - ry and z0 + rz <= z <= z1 - rz

    def _end_fits(self, tracker: Tracker) -> bool:
        """Outside the box: does a stop from the setpoint end inside the grown box (no further out than the
        tool point was, ``SLACK`` allowed for the path between)?"""
        plan = tracker.stop_plan()
        end = tracker.samples[0] if plan is None else plan[1](plan[0])
        grown = self._grown
        return _inside(self._tool(np.asarray(end)).tolist(), tuple(x - grown for x in self._lo),
                       tuple(x + grown for x in self._hi), 0.0)


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
